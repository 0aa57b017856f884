"""``fleetctl`` refuses bad arguments itself: one line on stderr, exit 2, and nothing sent.

The server named here listens nowhere: a command that sent a request would end with exit 3
(cannot reach) instead.
"""

from __future__ import annotations

import pytest

from tests.factories import ADMIN_TOKEN
from tests.fleetctl_run import fleetctl
from tests.live import free_port


@pytest.fixture
def nowhere() -> str:
    """A server URL nobody listens on."""
    return f"http://127.0.0.1:{free_port()}"


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (("goto", "Alpha", "nan", "15"), "LAT"),
        (("goto", "Alpha", "43.94", "inf"), "LON"),
        (("goto", "Alpha", "43.94", "-inf"), "LON"),
        (("goto", "Alpha", "43.94", "15", "--speed", "NaN"), "--speed"),
        (("station", "Alpha", "--lat", "inf", "--lon", "15"), "--lat"),
        (("station", "Alpha", "--radius", "nan"), "--radius"),
        (("path", "Alpha", "43.94,15", "nan,15"), "'nan,15'"),
        (("path", "Alpha", "43.94,15", "--speed", "infinity"), "--speed"),
        (("watch", "--seconds", "inf"), "--seconds"),
        (("alive", "--seconds", "inf"), "--seconds"),
        (("zones", "add", "Reef", "reef.geojson", "--clearance", "nan"), "--clearance"),
        (("failsafe", "set", "Alpha", "stop", "--after", "inf"), "--after"),
        (("failsafe", "set", "Alpha", "stop", "--low-battery", "nan"), "--low-battery"),
        (("failsafe", "set", "Alpha", "return_home", "--home", "43.94,-inf"), "--home"),
    ],
)
async def test_a_float_that_is_not_finite_is_refused_before_anything_is_sent(
    nowhere: str, args: tuple[str, ...], named: str
) -> None:
    refused = await fleetctl(nowhere, ADMIN_TOKEN, *args)
    assert refused.exit_code == 2, refused.output
    assert refused.stderr.count("\n") == 1 and named in refused.stderr
    assert refused.stdout == ""
