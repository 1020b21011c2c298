"""Emulated firmware of one robot: the HPS side (drivers, 5C loop) and the FPGA register model.

Importing the package first settles how its register model and drivers run (SWARM_NATIVE:
from source, or compiled by mypyc; robot_firmware/native.py)."""

from robot_firmware import native as native
