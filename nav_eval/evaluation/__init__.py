"""Closed-loop evaluation (`segmin nav-eval`): jobs over fields x methods x runs, the paper's Table 3 metrics, reports and figures."""
