"""Gaze control on the map: one fixation, closed-loop looks, smooth pursuit, and where exploration looks next."""
