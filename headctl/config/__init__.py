"""A head's YAML file read into typed objects before anything is constructed: the whole file, and its sections."""
