"""One module per ``backlash`` subcommand (see ``pipeline.cli``)."""
