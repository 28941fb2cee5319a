"""The errors of ``tof-fpn clean`` that more than one of its modules raise or catch."""

from __future__ import annotations

__all__ = ["NoFramesError"]


class NoFramesError(ValueError):
    """INPUT has no readable frame with a valid pixel to measure a data-driven stage on.

    Attributes:
        failures: ``(file, reason)`` of every file of INPUT, in order, saying why it gave none.
    """

    HEADLINE = "no readable frame with a valid pixel in INPUT"

    def __init__(self, failures: list[tuple[str, str]]) -> None:
        self.failures = list(failures)
        detail = "; ".join(f"{name}: {why}" for name, why in self.failures)
        super().__init__(f"{self.HEADLINE} ({detail})" if detail else self.HEADLINE)
