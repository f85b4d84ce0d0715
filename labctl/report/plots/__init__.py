"""The report's figures (matplotlib, Agg backend), one module per figure family."""
