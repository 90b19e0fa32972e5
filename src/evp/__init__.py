"""EVP: vision-based position estimation for drones and robots from a phone camera."""

__version__ = "0.1.0"
