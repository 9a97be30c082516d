"""Real delivery over HTTP: a server for stream exports (Range, ETags, pacing to a bandwidth trace),
a client that streams a bundle slot by slot with the simulator's scheduling, and a replay page.

Modules are imported on use (the server and the client need aiohttp):
:mod:`l3gs_opt.delivery.server`, :mod:`l3gs_opt.delivery.shaping`, :mod:`l3gs_opt.delivery.fetch`,
:mod:`l3gs_opt.delivery.replay`.
"""

__all__: list[str] = []
