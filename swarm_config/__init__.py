"""Configuration shared by the robots and the world: the scenario file and its parameter models.

Both `robot_firmware` (a robot loads its mission from the scenario) and `world` (the world
simulates the scenario) read these models, so they live in a package of their own that imports
only pydantic, yaml, numpy and the pure control math in `robot_firmware.control`.
"""
