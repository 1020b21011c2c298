"""Tests of the robot networking package."""
