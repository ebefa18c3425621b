"""Simulated world, people, skeleton detector and MAVLink rover."""
