"""The world: physics of the robot bodies, sensor synthesis, radio medium, scenarios, metrics."""
