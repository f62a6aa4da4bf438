"""A Foxglove WebSocket client for the live view's tests (test_live, test_live_view), on the
``websockets`` package: independent of the server's code."""

import asyncio
import json
import struct
import threading


class Client(threading.Thread):
    """Subscribes to ``topic`` and keeps the (subscription id, stamp, payload) of every message
    until ``n`` have come or the server closes."""

    def __init__(self, port, topic, n, path='/', junk=(), hold=None):
        super().__init__(daemon=True)
        self.hold = hold               # an Event: reads nothing after subscribing until it is set
        self.port, self.topic, self.n, self.path, self.junk = port, topic, n, path, junk
        self.got, self.info, self.schema = [], None, None
        self.error, self.closed = None, False

    def run(self):
        try:
            asyncio.run(self._main())
        except Exception as exc:  # noqa: BLE001 -- reported by the test
            self.error = exc

    async def _main(self):
        import websockets
        async with websockets.connect(f'ws://127.0.0.1:{self.port}{self.path}',
                                      subprotocols=['foxglove.sdk.v1']) as ws:
            for j in self.junk:
                await ws.send(j)
            try:
                while len(self.got) < self.n:
                    m = await asyncio.wait_for(ws.recv(), 120)
                    if isinstance(m, str):
                        msg = json.loads(m)
                        if msg['op'] == 'serverInfo':
                            self.info = msg
                        for ch in msg.get('channels', []):
                            if ch['topic'] == self.topic:
                                self.schema = ch
                                await ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
                                    {'id': 9, 'channelId': ch['id']}]}))
                                if self.hold is not None:
                                    await asyncio.to_thread(self.hold.wait, 120)
                    else:
                        op, sid, stamp = struct.unpack_from('<BIQ', m)
                        assert op == 1
                        self.got.append((sid, stamp, bytes(m[13:])))
            except websockets.exceptions.ConnectionClosed:
                self.closed = True
