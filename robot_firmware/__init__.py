"""Emulated firmware of one robot: the HPS side (drivers, 5C loop) and the FPGA register model."""
