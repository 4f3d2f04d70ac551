"""ISO 230-2 statistics, backlash targets, feature tables and feature rankings."""
