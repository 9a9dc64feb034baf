"""smspace: sensorimotor datasets in an MCAP data lake, the sensorimotor predictive network, and
the measures of how much of the structure of space it learned (docs/API.md)."""
