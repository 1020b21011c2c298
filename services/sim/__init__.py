"""`swarm sim`: the in-process batch simulator, run summaries and the paper's figures."""
