"""The command line; one module per command, each wrapping one library function."""

__all__: list[str] = []
