"""Mobile station: the Python streaming client (the phone page is served by the station)."""
