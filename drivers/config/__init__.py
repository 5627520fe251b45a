"""The config reader every layer shares: typed frozen dataclasses out of plain mappings, the YAML file, the messages."""
