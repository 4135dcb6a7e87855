"""One-off study commands (``python -m training.studies.<study>``): each answers one question
with the pipeline's libraries and writes its tables and figures; docs/ holds the results."""
