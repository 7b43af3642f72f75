"""The inverse problem: the objective E, its terms, the Gauss-Newton model, optimisers and uncertainty."""
