"""Studies built on single drops: Monte-Carlo, the placement and mount optimisers, sensitivities, test campaigns."""
