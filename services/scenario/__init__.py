"""`swarm scenario`: scenario files written for the user (swarm_config/generate.py)."""
