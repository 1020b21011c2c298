"""`swarm router`: the swarm's Zenoh router (Python zenoh in router mode)."""
