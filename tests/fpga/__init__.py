"""Tests of the FPGA register model."""
