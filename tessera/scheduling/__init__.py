"""The coordinator's frame scheduling without I/O: frames in flight, their roll-up, the scheduler."""
