"""Fusing the visual track with GPS and barometer: alignment, spoofing/jamming detection."""
