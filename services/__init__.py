"""Services around the swarm: command line, batch simulation, tuner, dashboard, launcher."""
