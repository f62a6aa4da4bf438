"""A live view of the twin (or of a bag being played) in the Foxglove app, over the Foxglove
WebSocket protocol (the ``foxglove-sdk`` package): every message the twin records is also
served, with its ROS 2 schema and exact CDR bytes, on ``ws://127.0.0.1:PORT`` -- in Foxglove,
"Open connection", "Foxglove WebSocket", that address. ``config/foxglove_layout.json`` is a
layout for the twin's topics."""

from __future__ import annotations

import threading
from typing import Mapping

from ..bag.writer import message_definition


class FoxgloveLive:
    """Serve ``types`` (topic -> ROS type name) on localhost at ``port`` (0: any free port)."""

    def __init__(self, types: Mapping[str, str], port: int = 8765, host: str = '127.0.0.1'):
        import foxglove
        from foxglove import Channel, Schema
        from foxglove.websocket import ServerListener
        #: set once a client has subscribed to a channel (tests and demos wait on it)
        self.subscribed = threading.Event()
        event = self.subscribed

        class _Listener(ServerListener):
            def on_subscribe(self, client, channel):
                event.set()
        self.context = foxglove.Context()
        try:
            self.server = foxglove.start_server(name='servovalve_twin', host=host, port=port,
                                                context=self.context,
                                                server_listener=_Listener())
        except Exception as exc:  # noqa: BLE001 -- e.g. the port is taken
            from ..errors import TwinError
            raise TwinError(f'cannot serve Foxglove on {host}:{port}: {exc}') from None
        self.channels = {}
        for topic, type_name in types.items():
            try:
                definition = message_definition(type_name).encode('utf-8')
            except Exception:  # noqa: BLE001 -- a type without a local .msg: no schema text
                definition = b''
            self.channels[topic] = Channel(
                topic, schema=Schema(name=type_name, encoding='ros2msg', data=definition),
                message_encoding='cdr', context=self.context)

    @property
    def port(self) -> int:
        return self.server.port

    def log(self, topic: str, data: bytes, t_ns: int) -> None:
        ch = self.channels.get(topic)
        if ch is not None:
            ch.log(data, log_time=int(t_ns))

    def close(self) -> None:
        self.server.stop()
