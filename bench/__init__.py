"""Benchmarks: ``python -m bench [--runs N] [--only NAME]`` runs every module and prints one table.

A bench module defines ``TITLE`` and ``run(runs: int) -> list[Metric]``: it
repeats each measurement ``runs`` times (sharing any costly set-up) and
returns the values; ``bench.__main__`` reports min / median / max.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class Metric:
    name: str
    unit: str
    values: list[float] = field(default_factory=list)
    #: ("min" | "max", bound): the goal the median must meet, if any.
    goal: tuple[str, float] | None = None

    def met(self, value: float) -> bool | None:
        if self.goal is None:
            return None
        kind, bound = self.goal
        return value >= bound if kind == "min" else value <= bound
