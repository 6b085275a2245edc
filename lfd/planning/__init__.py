"""Planning a learned task: the roadmap, biased sampling, step and edge costs, the spatiotemporal search."""
