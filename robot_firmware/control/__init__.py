"""Pure control core: kinematics, control law, fuzzy scheduler, formation, APF, trajectories.

Every function takes numpy arrays with arbitrary leading batch axes, so the same code steers one
robot in the firmware and thousands of candidate controllers in the tuner. Nothing here opens a
socket, starts a thread or reads a clock: time and randomness come in as arguments.
"""
