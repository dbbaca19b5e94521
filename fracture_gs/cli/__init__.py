"""Command-line front ends of the entry scripts (argparse, exit codes, progress, summaries)."""
