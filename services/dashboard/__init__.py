"""The live dashboard: a running swarm streamed into Rerun (web viewer and .rrd recording).

`cli` holds the `swarm dashboard` and `swarm replay` subcommands, `live` the Zenoh-to-Rerun
service, `scene` the pure mapping from truth and telemetry to Rerun records, `blueprint` the
default layout, `entities` every entity path, `replay` the serving of a recorded file.  The
payloads it reads are the swarm's typed messages (`robot_firmware/net/messages.py`).
"""
