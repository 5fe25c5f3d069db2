"""Live estimation: the runtime that filters the pose and command streams, alignment, the worker process."""
