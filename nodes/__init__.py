"""Built-in node library: one subpackage per kind. Each node is one file registered in pyproject.toml."""
