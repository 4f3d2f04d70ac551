"""backlash-pipeline: readings I/O, CLI, tracking, reports and drift monitoring."""
