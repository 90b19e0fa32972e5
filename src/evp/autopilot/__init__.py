"""Seed 003's autopilot: the state machine of its Figure 5 flying over a marker map (pure core:
marker observations and range readings in, commands out)."""
