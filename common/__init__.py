"""What both CLIs share and nothing else depends on: errors, CLI helpers, rerun output."""
