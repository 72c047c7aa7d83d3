"""Navigation: SegMin / SegMinD / SegZeros navigators and the closed-loop evaluator."""
