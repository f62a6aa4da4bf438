"""A live view of the twin (or of a bag being played) in the Foxglove app, over the Foxglove
WebSocket protocol (ws-protocol v1, subprotocols ``foxglove.sdk.v1`` and
``foxglove.websocket.v1``): every message the twin records is also served, with its ROS 2
schema and exact CDR bytes, on ``ws://127.0.0.1:PORT`` -- in Foxglove, "Open connection",
"Foxglove WebSocket", that address. ``config/foxglove_layout.json`` is a layout for the twin's
topics.

The server is this module's, on the ``websockets`` package, rather than ``foxglove-sdk``'s:
the SDK's server accepts any connection to its port and exposes no hook on the handshake, so it
could not refuse a web page open in a local browser (the live data of a test rig is not the
business of every site the engineer has open), nor wait, when a played bag ends, until the
viewer has its last messages (it dropped 700-1400 of 12 113 at ``-r 1000``). Only the part of
the protocol a viewer of recorded topics needs is spoken: server info, advertise, subscribe,
unsubscribe, message data.

Who may connect:

- the ``Host`` header must name the loopback address the server listens on (``127.0.0.1``,
  ``localhost`` or ``[::1]`` with its port): a DNS-rebinding page has its own host name there;
- an ``Origin`` header, which browsers send and other clients do not, must be one of
  :data:`ORIGINS` (the Foxglove web app, ``file://``) or one the user adds
  (:data:`ORIGINS_ENV`);
- with a token (``SERVOVALVE_TWIN_FOXGLOVE_TOKEN`` in the environment; not an option, as a
  command line is visible to every local user in ``ps``), the URL must carry it:
  ``ws://127.0.0.1:PORT/?token=TOKEN``.

Refusals and malformed client messages are counted and reported at most once a second
(:class:`_Throttled`), so a client cannot fill the twin's stderr.
"""

from __future__ import annotations

import asyncio
import collections
import hmac
import json
import logging
import os
import struct
import sys
import threading
import time
from typing import Mapping, Sequence
from urllib.parse import parse_qs, urlsplit

from ..bag.writer import message_definition
from ..errors import TwinError

#: the subprotocols served, in order of preference (the SDK's name, then ws-protocol v1's: the
#: messages used here are the same in both)
SUBPROTOCOLS = ('foxglove.sdk.v1', 'foxglove.websocket.v1')
#: Origin values accepted besides none (a client that is not a browser sends none): the
#: Foxglove web app, and ``file://``, which Electron pages loaded from disk send (a desktop
#: app that sends something else -- newer Chromium sends ``null``, as does any local HTML
#: file, so it is not accepted by default -- is named in the refusal: add it with
#: :data:`ORIGINS_ENV`)
ORIGINS = ('https://app.foxglove.dev', 'https://studio.foxglove.dev', 'file://')
#: the environment variable holding a token the clients must present (unset: no token)
TOKEN_ENV = 'SERVOVALVE_TWIN_FOXGLOVE_TOKEN'
#: the environment variable listing more accepted origins, comma-separated (a self-hosted
#: Foxglove, e.g. ``http://rig.local:8080``)
ORIGINS_ENV = 'SERVOVALVE_TWIN_FOXGLOVE_ORIGINS'
#: messages held per client before the oldest are dropped (a live twin) or the producer waits
#: (a played bag): ~26 s of one 1 kHz topic, a few MB
BACKLOG = 1 << 15
#: how long :meth:`FoxgloveLive.close` waits for the clients to take what is queued for them
DRAIN_S = 30.0
#: a client that takes nothing for this long [s] while its queue is full is disconnected, with
#: one line: a viewer that never read held ``play --foxglove`` (and every ROS subscriber of the
#: played topics) without bound -- 162 018 messages took 378 s instead of 41
SEND_DEADLINE_S = 5.0
#: the most clients served at once; one more is answered 503 (500 silent clients cost the
#: live twin 354 MB)
MAX_CLIENTS = 16
#: Message Data: opcode 1, subscription id (uint32), log time (uint64 ns), payload
_DATA = struct.Struct('<BIQ')


class _Throttled:
    """Counted events reported on stderr at most once per ``period`` s (the first at once)."""

    def __init__(self, what: str, period: float = 1.0):
        self.what, self.period = what, period
        self.count = 0
        self._reported, self._last = 0, -float('inf')

    def __call__(self, detail: str) -> None:
        self.count += 1
        now = time.monotonic()
        if now - self._last >= self.period:
            more = self.count - self._reported - 1
            tail = f' (and {more} more since the last report)' if more > 0 else ''
            print(f'foxglove: {self.what}: {detail}{tail}', file=sys.stderr, flush=True)
            self._reported, self._last = self.count, now


class _Client:
    """One connection: its subscriptions and the frames queued for it."""

    def __init__(self, ws, loop: asyncio.AbstractEventLoop):
        self.ws = ws
        self.subs: dict[int, int] = {}          # subscription id -> channel id
        self.queue: collections.deque = collections.deque()
        self.wake = asyncio.Event()
        self.wake_pending = False                # a wake-up is scheduled on the loop
        self.room = threading.Event()            # the queue fell below BACKLOG
        #: frames queued (by the producer), sent and dropped: all delivered when equal
        self.pushed = self.sent = self.dropped = 0
        self.open = True
        self.loop = loop
        #: when the client last took a frame (or connected): its send deadline runs from here
        self.progress = time.monotonic()

    def push(self, frame: bytes) -> None:
        """From the producer's thread (deque appends are atomic)."""
        self.pushed += 1
        if not self.queue:
            # it had taken everything: idle for want of data, not slow
            self.progress = time.monotonic()
        self.queue.append(frame)
        if not self.wake_pending:
            self.wake_pending = True
            self.loop.call_soon_threadsafe(self.wake.set)


class FoxgloveLive:
    """Serve ``types`` (topic -> ROS type name) on ``host`` (loopback) at ``port`` (0: any free
    port). ``block``: :meth:`log` waits while a client's queue is full (a played bag: every
    message reaches the viewer) instead of dropping its oldest (the live twin: it never waits
    on a viewer). ``origins``: more Origin values to accept, besides :data:`ORIGINS_ENV`'s;
    ``token``: default from :data:`TOKEN_ENV`."""

    def __init__(self, types: Mapping[str, str], port: int = 8765, host: str = '127.0.0.1', *,
                 block: bool = False, origins: Sequence[str] = (), token: str | None = None,
                 backlog: int = BACKLOG, send_deadline: float = SEND_DEADLINE_S,
                 max_clients: int = MAX_CLIENTS):
        try:
            from websockets.asyncio.server import serve
        except ImportError:
            raise TwinError('the live view needs the websockets package: pip install '
                            'websockets') from None
        self.block, self.backlog = block, backlog
        self.send_deadline, self.max_clients = send_deadline, max_clients
        #: clients disconnected for taking nothing within the send deadline
        self.slow_clients = 0
        more = [o.strip() for o in os.environ.get(ORIGINS_ENV, '').split(',') if o.strip()]
        self.origins = (None, *ORIGINS, *more, *origins)
        self.token = (os.environ.get(TOKEN_ENV) or None) if token is None else token
        self.host = host
        #: set once a client has subscribed to a channel (tests and demos wait on it)
        self.subscribed = threading.Event()
        self.refused = _Throttled('refused a connection')
        self.malformed = _Throttled('ignored a client message')
        self.dropped = 0
        self.channels: dict[str, dict] = {}
        for i, (topic, type_name) in enumerate(types.items(), start=1):
            try:
                definition = message_definition(type_name)
            except Exception:  # noqa: BLE001 -- a type without a local .msg: no schema text
                definition = ''
            self.channels[topic] = {'id': i, 'topic': topic, 'encoding': 'cdr',
                                    'schemaName': type_name, 'schema': definition,
                                    'schemaEncoding': 'ros2msg'}
        #: channel id -> ((client, subscription id), ...): replaced whole by the loop's thread,
        #: read by the producer's without a lock
        self._targets: dict[int, tuple] = {}
        self._clients: set[_Client] = set()
        self.loop = asyncio.new_event_loop()
        quiet = logging.getLogger('servovalve_twin.foxglove')
        quiet.propagate, quiet.disabled = False, True    # refusals are reported throttled
        started: dict = {}

        async def start():
            try:
                server = await serve(
                    self._serve, host, port, subprotocols=list(SUBPROTOCOLS),
                    process_request=self._check, logger=quiet, compression=None)
            except Exception as exc:  # noqa: BLE001 -- e.g. the port is taken: said below
                started['error'] = exc
                return
            # before the first handshake: _check compares the Host header with it
            self.port = server.sockets[0].getsockname()[1]
            started['server'] = server

        def run():
            asyncio.set_event_loop(self.loop)
            self.loop.run_until_complete(start())
            ready.set()
            if 'server' in started:
                self.loop.run_forever()
        ready = threading.Event()
        self.thread = threading.Thread(target=run, name='foxglove', daemon=True)
        self.thread.start()
        ready.wait()
        if 'error' in started:
            self.thread.join()
            self.loop.close()
            raise TwinError(f'cannot serve Foxglove on {host}:{port}: {started["error"]}')
        self.server = started['server']
        # the address to open in Foxglove (with port 0 the system chose it)
        print(f'live view for Foxglove on ws://{host}:{self.port}'
              + (' (the URL needs ?token=)' if self.token else ''), file=sys.stderr, flush=True)

    # -- the loop's thread ---------------------------------------------------------------------

    def _check(self, connection, request):
        """Refuse (403) a handshake from another host name, a foreign origin or without the
        token, and (503) one past :data:`MAX_CLIENTS`; None lets it go on."""
        hosts = {f'{h}:{self.port}' for h in ('127.0.0.1', 'localhost', '[::1]', self.host)}
        # every value: two Host or Origin headers made .get() raise (HTTP 500, not refused)
        host_values = request.headers.get_all('Host')
        origin_values = request.headers.get_all('Origin')
        origin = origin_values[0] if len(origin_values) == 1 else None
        if len(host_values) != 1 or host_values[0] not in hosts:
            why = f'Host {host_values!r} is not this server ({", ".join(sorted(hosts))})'
        elif len(origin_values) > 1 or origin not in self.origins:
            why = (f'Origin {origin_values!r} is not one of '
                   f'{", ".join(o for o in self.origins if o)}')
        elif self.token is not None and not hmac.compare_digest(
                (parse_qs(urlsplit(request.path).query).get('token') or [''])[0].encode(),
                self.token.encode()):
            why = f'no valid token (the URL needs ?token= the value of {TOKEN_ENV})'
        elif len(self._clients) >= self.max_clients:
            self.refused(f'{len(self._clients)} clients connected already (at most '
                         f'{self.max_clients})')
            return connection.respond(503, 'Service Unavailable\n')
        else:
            return None
        self.refused(why)
        return connection.respond(403, 'Forbidden\n')

    async def _serve(self, ws) -> None:
        client = _Client(ws, self.loop)
        self._clients.add(client)
        sender = asyncio.ensure_future(self._send(client))
        try:
            await ws.send(json.dumps({'op': 'serverInfo', 'name': 'servovalve_twin',
                                      'capabilities': [], 'metadata': {},
                                      'sessionId': str(time.time_ns())}))
            await ws.send(json.dumps({'op': 'advertise',
                                      'channels': list(self.channels.values())}))
            async for message in ws:
                self._receive(client, message)
        except Exception:  # noqa: BLE001 -- a connection lost: the client is forgotten below
            pass
        finally:
            client.open = False
            client.room.set()
            self._clients.discard(client)
            client.subs.clear()
            self._retarget()
            sender.cancel()

    def _receive(self, client: _Client, message) -> None:
        try:
            if isinstance(message, bytes):
                raise ValueError('binary messages are not accepted (no client publishing)')
            msg = json.loads(message)
            op = msg['op']
            if op == 'subscribe':
                known = {c['id'] for c in self.channels.values()}
                for sub in msg['subscriptions']:
                    sid, cid = int(sub['id']), int(sub['channelId'])
                    if (cid not in known or sid in client.subs or cid in client.subs.values()
                            or not 0 <= sid < 2 ** 32):
                        raise ValueError(f'subscription {sid} to channel {cid} refused')
                    client.subs[sid] = cid
            elif op == 'unsubscribe':
                for sid in msg['subscriptionIds']:
                    client.subs.pop(int(sid), None)
            else:
                raise ValueError(f'op {op!r} is not served')
        except Exception as exc:  # noqa: BLE001 -- any malformed message: counted, ignored
            self.malformed(f'{type(exc).__name__}: {str(exc)[:200]}')
            return
        finally:
            self._retarget()
        if client.subs:
            self.subscribed.set()

    def _retarget(self) -> None:
        targets: dict[int, list] = {}
        for c in self._clients:
            for sid, cid in c.subs.items():
                targets.setdefault(cid, []).append((c, sid))
        self._targets = {cid: tuple(v) for cid, v in targets.items()}

    async def _send(self, client: _Client) -> None:
        q = client.queue
        while True:
            await client.wake.wait()
            client.wake.clear()
            client.wake_pending = False
            while q:
                frame = q.popleft()
                if len(q) < self.backlog:
                    client.room.set()
                await client.ws.send(frame)
                client.sent += 1
                client.progress = time.monotonic()

    # -- the producer's thread -----------------------------------------------------------------

    def log(self, topic: str, data: bytes, t_ns: int) -> None:
        ch = self.channels.get(topic)
        if ch is None:
            return
        targets = self._targets.get(ch['id'])
        if not targets:
            return
        for client, sid in targets:
            if not client.open:
                continue
            if len(client.queue) >= self.backlog:
                if self._stalled(client):
                    continue
                if not self.block:
                    try:
                        client.queue.popleft()       # a live view shows the newest
                        client.dropped += 1
                        self.dropped += 1
                    except IndexError:               # the sender took it meanwhile
                        pass
                else:
                    while client.open and len(client.queue) >= self.backlog:
                        if self._stalled(client):
                            break
                        client.room.clear()
                        if len(client.queue) >= self.backlog:
                            client.room.wait(0.1)
                    if not client.open:
                        continue
            client.push(_DATA.pack(1, sid, int(t_ns)) + bytes(data))

    def _stalled(self, client: _Client) -> bool:
        """Whether ``client`` has taken nothing within the send deadline; such a client is
        disconnected, with one line, and nothing more is queued or waited for it."""
        idle = time.monotonic() - client.progress
        if idle <= self.send_deadline:
            return False
        client.open = False
        client.room.set()
        self.slow_clients += 1
        print(f'foxglove: disconnected a client that took nothing for {idle:.1f} s (send '
              f'deadline {self.send_deadline:g} s); the others go on', file=sys.stderr,
              flush=True)

        def abort():
            self._clients.discard(client)
            self._retarget()
            transport = getattr(client.ws, 'transport', None)
            if transport is not None:
                transport.abort()            # its sends may wait on a full socket for ever
        self.loop.call_soon_threadsafe(abort)
        return True

    def close(self, drain_s: float = DRAIN_S) -> None:
        """Let the clients take what is queued for them (up to ``drain_s`` s), then close their
        connections and the server; report messages dropped for a slow client."""
        if self.loop.is_closed():
            return
        deadline = time.monotonic() + drain_s
        for client in list(self._clients):
            while (client.open and client.sent + client.dropped < client.pushed
                   and time.monotonic() < deadline and not self._stalled(client)):
                time.sleep(0.01)

        async def stop():
            self.server.close()
            await self.server.wait_closed()
        asyncio.run_coroutine_threadsafe(stop(), self.loop).result(drain_s + 10)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join()
        self.loop.close()
        if self.dropped:
            print(f'foxglove: {self.dropped} messages dropped for a client that did not keep '
                  f'up (each client holds the newest {self.backlog})', file=sys.stderr)
