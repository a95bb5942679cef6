"""Reading and writing pose-graph files."""
