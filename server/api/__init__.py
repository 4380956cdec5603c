"""The HTTP API: the FastAPI app, its routes, request checks and uploads."""
