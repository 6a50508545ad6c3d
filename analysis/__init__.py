"""Flight analysis: geodesy, the paper's task metrics, plots and comparisons."""
