"""quadnav: GPS-denied quadrotor navigation.

Packages, from the bottom up: ``geometry``, ``messages``, ``sim``/``estimation``/``control``,
``experiments`` (closed loops wiring those together), ``io``, ``eval``, ``cli``.
"""

from quadnav.errors import QuadnavError

__all__ = ["QuadnavError", "__version__"]

__version__ = "0.1.0"
