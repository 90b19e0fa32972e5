"""Image features: ORB extraction with an even spatial spread, descriptor matching."""
