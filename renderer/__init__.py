"""The bundled CPU splat renderer, image metrics, procedural scenes and the trainer (PyTorch).

Filled by the renderer and trainer issues; importing this package needs nothing yet.
"""

__all__: list[str] = []
