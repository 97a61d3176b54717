"""Commands of `python -m companion` that grew a module of their own (option parsing, console
output and report writing), kept apart from the core."""
