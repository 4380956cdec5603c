"""jointseg job service (FastAPI + Huey). Depends on `jointseg`, never the other way."""
