"""A worker process: claiming jobs from the queue and running them, big scans in tiles."""
