"""`swarm up` and friends: start, supervise, kill and restart a swarm's processes locally."""
