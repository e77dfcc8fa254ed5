"""The inverse-dynamics regression: the recording's states (states), the candidate effects' residual columns
(library), held-out least squares (fitting), forward selection (selection) and what the data pins (identify)."""
