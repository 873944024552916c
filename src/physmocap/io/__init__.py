"""Reading and writing files: videos, observations, results, animation exports."""
