"""The job table and its state machines: jobs and their parts (tiles, merges), the reaper."""
