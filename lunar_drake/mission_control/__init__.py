"""Mission control: what the ground received, served live and recorded.

:mod:`.dictionary` names every telemetry point (units, formats) and turns what the ground
received into datums; :mod:`.store` keeps them for history queries and realtime
subscribers; :mod:`.live` is the simulation side of a live mission (an observer that
publishes each ground tick's news and applies commands from the network);
:mod:`.server` is the aiohttp server under the Open MCT page (``web/``);
:mod:`.replay` loads a finished run; :mod:`.recording` writes ``run.mcap`` for Foxglove.
Everything here sees only what the ground received (stamped with reception time).
"""
