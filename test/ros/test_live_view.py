"""The live view in the Foxglove app: a Foxglove WebSocket client connects to the twin (and to
a bag being played), subscribes, and receives the exact CDR bytes that the bag records."""

import json
import re
import threading

from servovalve_twin.bag.reader import read_bag
from servovalve_twin.twin import Twin, TwinConfig
from conftest import ROOT
from foxclient import Client

SHORT = {'duration': 0.05, 'com': [[0.0, 0.02]]}


def test_a_foxglove_client_receives_the_twins_topics(ros_context, tmp_path):
    with Twin(TwinConfig('C2', SHORT, bag=tmp_path / 'b', foxglove=0), context=ros_context) as twin:
        client = Client(twin.live.port, '/xj', 51)
        client.start()
        assert twin.live.subscribed.wait(120), client.error
        twin.run()
    client.join(120)
    assert client.error is None and len(client.got) == 51
    assert client.schema['encoding'] == 'cdr' and client.schema['schemaName'] == \
        'std_msgs/msg/Float64' and 'float64 data' in client.schema['schema']
    from mcap.reader import make_reader
    with open(tmp_path / 'b' / 'b_0.mcap', 'rb') as fh:
        recorded = [(m.log_time, m.data) for _, c, m in make_reader(fh).iter_messages(
            topics=['/xj'], log_time_order=True)]
    # exact bytes, simulated time
    assert [(stamp, data) for _, stamp, data in client.got] == recorded


def test_play_serves_a_bag_to_foxglove(ros_context):
    from servovalve_twin.nodes.player import PlayOptions, play
    ref = ROOT / 'servovalve_twin' / 'data' / 'paper_HD'
    holder = {}

    def ready(player):           # start paused; resume once the client has subscribed
        holder['player'] = player
    opts = PlayOptions(rate=1000.0, topics=('/p12',), start_paused=True)
    done = {}

    def run():
        done['r'] = play(ref, opts, context=ros_context, foxglove=0, on_ready=ready,
                         progress=False)
    t = threading.Thread(target=run, daemon=True)
    t.start()
    for _ in range(1200):
        if 'player' in holder and holder['player'].sinks:
            break
        threading.Event().wait(0.1)
    player = holder['player']
    live = player.sinks[0].__self__
    client = Client(live.port, '/p12', 1001)
    client.start()
    assert live.subscribed.wait(120), client.error
    player._set_paused(False)
    t.join(300)
    client.join(120)
    assert client.error is None and len(client.got) == 1001
    run_ = read_bag(ref)
    import struct
    values = [struct.unpack('<d', p[4:])[0] for _, _, p in client.got]
    assert values == run_.series['/p12'][1].tolist()


def test_the_shipped_layout_names_the_twins_topics():
    layout = json.loads((ROOT / 'config' / 'foxglove_layout.json').read_text())
    from servovalve_twin.nodes.topics import TOPICS
    from servovalve_twin.nodes.monitor import MONITOR_TOPICS
    known = {f'/{t}' for t in list(TOPICS) + list(MONITOR_TOPICS)}
    paths = [p['value'] for c in layout['configById'].values() for p in c.get('paths', [])]
    topics = {re.match(r'(/[\w/]+)\.', p).group(1) for p in paths}
    assert topics and topics <= known, topics - known
    assert set(_panels(layout['layout'])) == set(layout['configById'])


def _panels(node):
    if isinstance(node, str):
        return [node]
    return _panels(node['first']) + _panels(node['second'])
