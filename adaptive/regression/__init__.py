"""Recursive least squares on user regressors and grey-box structures."""
