"""Learning a task model from demonstrations: the data formats, DTW, the EM fit, the model."""
