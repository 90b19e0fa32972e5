"""WiFi RSS fingerprinting (seed 001): a radio map from survey samples, and locating a scan in it.

Pure computation: fingerprints and scans in as arrays, positions and floors out; the UJI
long-term files are read by :mod:`evp.io.wifi_uji`.
"""
