"""Wire models shared by the server, the vehicle agent and the operator tools.

One definition of every message of the contract (``docs/api.md``).
This package depends on pydantic alone so that a vehicle can install it
without anything of the server's.
"""

from fleet_protocol.admin import *  # noqa: F403
from fleet_protocol.audit import *  # noqa: F403
from fleet_protocol.client import *  # noqa: F403
from fleet_protocol.commands import *  # noqa: F403
from fleet_protocol.common import *  # noqa: F403
from fleet_protocol.errors import *  # noqa: F403
from fleet_protocol.fleet import *  # noqa: F403
from fleet_protocol.media import *  # noqa: F403
from fleet_protocol.obstacles import *  # noqa: F403
from fleet_protocol.served import *  # noqa: F403
from fleet_protocol.text import *  # noqa: F403
from fleet_protocol.upper import *  # noqa: F403
from fleet_protocol.values import *  # noqa: F403
from fleet_protocol.ws import *  # noqa: F403
from fleet_protocol.ws_frames import *  # noqa: F403
from fleet_protocol.zones import *  # noqa: F403
