"""The live view of the head in Foxglove: a Foxglove WebSocket server of the eyes' images with
their annotations, the joint states, the frames and the learning curves (docs/foxglove.md)."""
