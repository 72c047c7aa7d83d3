"""`segmin navigate-demo`: the navigators on analytic row scenes, with no simulator and no model."""
