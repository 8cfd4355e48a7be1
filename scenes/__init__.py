"""Built-in scenes. `analytic`: a pier of closed-form primitives and a sonar orbit over it."""

from . import analytic

__all__ = ["analytic"]
