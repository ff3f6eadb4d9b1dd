"""Tests of the project as a whole: packaging, README commands, the device check, the contract with LeRobot."""
