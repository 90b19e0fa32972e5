"""Base station: link protocol, sessions, recording, operator web UI, MAVLink output."""
