"""``mrswarm gcs web``: the self-contained live map (the server in server.py, the page in static/)."""
