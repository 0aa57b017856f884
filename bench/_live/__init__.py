"""Issue 3: the live path over WebSocket, side by side with Mosquitto, in one run.

Starts a real ``fleet-server`` (``python -m server.cli``: uvicorn, uvloop,
permessage-deflate off, the embedded store in a temporary directory, rate
limits raised for the bench) as a subprocess pinned to core 0, and Mosquitto
brokers (QoS 0, ``set_tcp_nodelay``) on free loopback ports, pinned to core 0
too; the bench itself (every client) runs in this one asyncio process (uvloop)
pinned to core 1, the capacity load in worker processes on the cores but the
server's (``loadgen``). Sections:

1. **pub-sub**: one-hop latency for 100 B and 64 KiB (a publisher on
   ``/ws/client`` publishing to ``user/<name>/x``, a subscriber on another
   ``/ws/client`` connection; one message in flight) against Mosquitto QoS 0
   (``bench.pubsub_mqtt.mqtt_one_hop``), and throughput one publisher to one
   subscriber (100 B, at most ``WINDOW`` messages in flight, none lost).
2. **command**: ``POST /client/submit_control`` until the ``command`` push is
   read on the vehicle's ``/ws/vehicle`` socket, with 1, 100 and 1,000
   vehicles connected (each ``start_instance``'d on its socket); the
   operator holds a lease granted by the admin; the vehicle acks each one.
3. **capacity**: vehicles at 1 Hz telemetry over ``/ws/vehicle``
   (``update_param`` with one sample and an ``id``; ack latency), ramping up
   (``--levels``, default 1,000 / 5,000 / 10,000), the vehicles' sockets shared
   out over ``--gen-procs`` worker processes; server CPU (% of one core) and
   RSS by psutil, the generator's CPU (its processes summed), errors, and which
   side bounds it.
4. **three-layer**: unit -> gateway -> cloud -> operator (an in-bench
   gateway relay: a local WebSocket server the unit connects to, forwarding
   over one gateway ``/ws/vehicle`` connection as ``publish`` with
   ``vehicle_id``) against two bridged Mosquitto brokers.

Each figure is min / median / max over ``--runs`` runs (batches on the same
connections). Every loop is bounded in count and time; everything runs on
127.0.0.1; every process started here is stopped at the end.

The entry points are ``bench/live_ws.py`` (``python -m bench.live_ws`` and
``python -m bench --only live_ws``); the package holds one concern a module:
``config`` (constants, goals, the command line), ``server`` (the fleet-server
subprocess), ``clients`` (WebSocket and raw HTTP clients), ``world`` (vehicles,
users, a gateway), ``loadgen`` (the capacity load's worker processes, started and
asked for figures), ``loadgen_worker`` (one worker: its vehicles, ticker and counters),
``rawws`` (their minimal WebSocket client), ``pubsub``, ``command``, ``capacity`` and
``layers`` (the four sections), ``runner`` (one run), ``report`` (the printed table) and
``metrics`` (rows of ``python -m bench``'s table). Mosquitto, child processes
and latency statistics are shared with ``bench.pubsub_mqtt`` through
``bench._mosquitto``, ``bench._proc`` and ``bench._stats``.
"""
