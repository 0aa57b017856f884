"""The one clock type: a function that tells the time (UTC-aware). Tests pass a fake one."""

from __future__ import annotations

from collections.abc import Callable
from datetime import datetime

Clock = Callable[[], datetime]
