"""jointseg viewer (viser scene and job page). Depends on `server` and `jointseg`."""
