"""smspace-bench: versioned suites of tasks, the entries measured on them, and their leaderboard
(docs/BENCHMARK.md)."""
