"""The setup assistant: which servo turns which joint, read off the images, and the config it writes."""
