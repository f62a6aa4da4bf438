"""Commands that start ROS 2 nodes: run (the twin), replay, play."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ..errors import TwinError
from .common import (Command, add_foxglove_option, add_param_options, discovery_off,
                     overrides, positive_float)


class Run(Command):
    name = 'run'
    help = 'the ROS 2 twin (four nodes, one executor, simulated time) on a scenario, recorded ' \
           'as a bag'

    def add_arguments(self, p):
        from ..twin.config import TwinConfig
        TwinConfig.add_arguments(p)        # the twin executable's options, the same table
        add_param_options(p)
        p.add_argument('--out', metavar='FILE.csv', help="the CSV of simulate, from the run's "
                                                        'own messages')
        p.add_argument('--progress', action='store_true',
                       help="print 'flushed up to T s' each time the bag is flushed (50 ms)")
        p.add_argument('--discoverable', action='store_true',
                       help='keep DDS discovery on (to watch the topics from other processes);'
                            ' by default the run is confined to its process, unless '
                            '--namespace, --clock follow, --followers or --real-time-factor '
                            'is given')

    def main(self, args):
        from ..twin.config import TwinConfig
        config = TwinConfig.from_args(args)
        with discovery_off(not (args.discoverable or config.shares_the_graph)):
            return self._run(args, config)

    def _run(self, args, config) -> int:
        from ..config import load_scenario
        from ..progress import enabled, progress
        from ..runs import write_table
        from ..twin import run_twin
        scenario = load_scenario(config.scenario)
        if args.out and args.out != '-' and not Path(args.out).resolve().parent.is_dir():
            raise TwinError(f'--out {args.out}: directory {str(Path(args.out).parent)!r} does '
                            'not exist')
        bar = progress(total=int(round(scenario.duration * 1000)), desc='run', unit='ms') \
            if enabled() and not args.progress else None
        result = run_twin(dataclasses.replace(config, scenario=scenario), overrides(args),
                          on_tick=(lambda k, twin: bar.update(twin.period_ns * 1e-6) if k
                                   else None) if bar is not None else None,
                          keep_values=args.out is not None,
                          on_flush=(lambda t: print(f'flushed up to {t:.3f} s', flush=True))
                          if args.progress else None)
        if bar is not None:
            bar.close()
        if args.out:
            write_table(args.out, result.signals)
        sim_s = result.simulated_s
        print(f'{result.valve_model} on {scenario.name}: {sim_s:.3f} s simulated in '
              f'{result.wall_s:.3f} s (real-time factor {sim_s / max(result.wall_s, 1e-9):.1f})'
              + (f'; bag {result.bag}' if result.bag else '')
              + (f'; CSV {args.out}' if args.out else '')
              + ('; INTERRUPTED' if result.interrupted else ''))
        for line in result.verdicts:
            print(line)
        return 130 if result.interrupted else 0


class Replay(Command):
    name = 'replay'
    help = "drive the ECU and plant with a bag's inputs, record, compare with the bag"

    def add_arguments(self, p):
        p.add_argument('bag', metavar='BAG', help='the recorded bag (or @paper_HD)')
        p.add_argument('--valve-model', metavar='NAME', help="default: the bag's")
        p.add_argument('--out', metavar='DIR',
                       help='new bag (default bags/<BAG>_replay_<model>_<UTC time>)')
        p.add_argument('--overwrite', action='store_true',
                       help="replace the bag in an existing --out directory (only the bag's "
                            'files)')
        add_param_options(p)

    def main(self, args):
        from ..apps.compare import format_table
        from ..apps.replay import replay
        with discovery_off():
            _, result, metrics = replay(args.bag, valve_model=args.valve_model, out=args.out,
                                        overrides=overrides(args), overwrite=args.overwrite)
        print(f'replayed {args.bag} with {result.valve_model} into {result.bag}; new run '
              'against the bag:')
        print(format_table(metrics))
        return 130 if result.interrupted else 0


class Play(Command):
    name = 'play'
    help = 'put a rosbag2 bag (MCAP or sqlite3, any version) back on the ROS graph, like ' \
           'ros2 bag play'

    def add_arguments(self, p):
        p.add_argument('bag', metavar='BAG', help='bag directory, .mcap or .db3 file')
        p.add_argument('-r', '--rate', type=positive_float, default=1.0, metavar='FACTOR',
                       help='playback rate (wall pacing; default 1.0)')
        p.add_argument('--clock', type=positive_float, nargs='?', const=40.0, default=0.0,
                       metavar='HZ', help='publish /clock from the bag time (default 40 Hz '
                       "when given); the bag's own /clock is then not republished")
        p.add_argument('--topics', nargs='+', default=[], metavar='T', help='play only these')
        p.add_argument('--exclude-topics', nargs='+', default=[], metavar='T',
                       help='do not play these')
        p.add_argument('-l', '--loop', action='store_true', help='play again from the start')
        p.add_argument('-d', '--delay', type=float, default=0.0, metavar='S',
                       help='wall time to wait before playing')
        p.add_argument('--start-offset', type=float, default=0.0, metavar='S',
                       help='start this far into the bag')
        p.add_argument('--playback-duration', type=float, default=0.0, metavar='S',
                       help='play only this much bag time (default: to the end)')
        p.add_argument('-p', '--start-paused', action='store_true',
                       help='start paused (resume with the ~/resume service)')
        p.add_argument('--remap', nargs='+', default=[], metavar='FROM:=TO',
                       help='publish topic FROM as TO')
        p.add_argument('--wait-for-subscribers', type=int, default=0, metavar='N',
                       help='play once every played topic has N matched subscribers (default '
                            '0: once the subscribers already on the graph are matched, at '
                            'most 5 s)')
        add_foxglove_option(p)

    def main(self, args):
        from ..nodes.player import PlayOptions, play
        from ..nodes.process import ros_main
        opts = PlayOptions(rate=args.rate, clock=args.clock, topics=tuple(args.topics),
                           exclude_topics=tuple(args.exclude_topics), loop=args.loop,
                           delay=args.delay, start_offset=args.start_offset,
                           playback_duration=args.playback_duration,
                           start_paused=args.start_paused, remap=tuple(args.remap),
                           wait_for_subscribers=args.wait_for_subscribers)
        opts.check()

        def body(context, stopped) -> int:
            result = play(args.bag, opts, context=context, stop=stopped,
                          foxglove=args.foxglove)
            state = 'stopped' if stopped() else 'done'
            print(f'play: {state}: {result["published"]} messages in {result["wall_s"]:.2f} s '
                  f'(bag {result["bag_duration_s"]:.3f} s at rate {args.rate:g})')
            return 0
        return ros_main('servovalve-twin play', body)
