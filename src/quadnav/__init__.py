"""quadnav: GPS-denied quadrotor navigation.

Packages, from the bottom up (ARCHITECTURE.md, enforced by ``tests/test_layers.py``):
``geometry``, ``messages``; ``sim``, ``estimation``, ``vision``, ``control``; ``io``; ``eval``;
``experiments`` (closed loops, studies and replays wiring those together); ``cli``.
"""

from quadnav.errors import QuadnavError

__all__ = ["QuadnavError", "__version__"]

__version__ = "0.1.0"
