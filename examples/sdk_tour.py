"""A tour of the operator SDK (``remote_client.sdk.FleetClient``), run against a server:

    FLEET_SERVER=http://127.0.0.1:8000 FLEET_TOKEN=<operator token> \\
        python examples/sdk_tour.py "H2OmniX Alpha"

It lists the fleet, reads one vehicle's parameters and latest position (by its name or
id), its last hour of events and samples, asks for control (unless the token holds it
already), sends a ``go_to`` 50 m north if control is granted (else prints the refusal),
then prints the vehicle's latest sample and the next one as they come live.
``docs/sdk.md`` walks through it.
"""

from __future__ import annotations

import asyncio
import os
import sys

from remote_client.sdk import FleetApiError, FleetClient

NORTH_50_M = 50 / 111_320  # degrees of latitude


async def tour(server: str, token: str, boat: str) -> None:
    async with FleetClient(server, token) as fleet:
        for v in (await fleet.vehicles())["vehicles"]:
            print(f"{v['vehicle_id']:<14} {v['name']:<16} {v['presence']:<8} {v['position']}")

        [instance_id] = await fleet.instance_ids_of([boat])  # a name, an id or an instance
        state = await fleet.params(instance_id)
        print("params:", state["params"], "position:", state["position"])

        vehicle_id = await fleet.vehicle_id_of(boat)
        events = await fleet.event_log(vehicle_id=vehicle_id, since="1h")
        print("events in the last hour:", [e["kind"] for e in events["events"]])
        async for page in fleet.telemetry_pages(vehicle_id, since="1h"):
            print("samples:", len(page), "from seq", page[0]["seq"] if page else None)
            break

        try:
            await fleet.request_control(instance_id)  # a manager grants it (or not)
        except FleetApiError as asked:
            if asked.code != "control_held":  # held already (a grant): nothing to ask
                print("request refused:", asked.status, asked.code, asked.message)
        try:
            here = state["position"]
            sent = await fleet.go_to(instance_id, here["lat"] + NORTH_50_M, here["lon"])
            print("go_to:", sent["commands"][0]["status"], sent["warnings"])
        except FleetApiError as refused:  # e.g. 409 control_not_held until it is granted
            print("refused:", refused.status, refused.code, refused.message)

        seen = 0
        topic = f"vehicle/{vehicle_id}/telemetry"
        async for event in fleet.events([topic]):  # the current state first, then changes
            sample = event.get("data") or {}
            said = "snapshot" if event.get("snapshot") else "change"
            print(event["op"], said, "seq", sample.get("seq"), sample.get("lat"), sample.get("lon"))
            seen += 1
            if seen == 2:
                break


def main() -> None:
    server = os.environ.get("FLEET_SERVER", "http://127.0.0.1:8000")
    token = os.environ.get("FLEET_TOKEN")
    if not token or len(sys.argv) != 2:
        sys.exit("usage: FLEET_TOKEN=<token> python examples/sdk_tour.py VEHICLE")
    asyncio.run(tour(server, token, sys.argv[1]))


if __name__ == "__main__":
    main()
