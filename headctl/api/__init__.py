"""The outer layer: the HTTP control API (FastAPI app, server thread), its client, the metrics and the dashboard."""
