"""The simulated head: servos with a motion model, cameras that render a textured room through fish-eye lenses, moving objects."""
