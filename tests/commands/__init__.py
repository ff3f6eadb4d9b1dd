"""Tests of the command line (cli.py, commands/): presets, bad inputs, stock lerobot-train."""
