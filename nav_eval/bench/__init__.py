"""Speed figures: `segmin bench nav-eval` (closed loop) and `segmin bench navigator` (navigators, runtime)."""
