"""Paper figures and tables from the MLflow store:
``python -m sweep.report [--experiment] [--sweep] [--out] [--by KEY[,KEY...]] [--baseline KEY=VALUE]``.

load (MLflow -> pandas) -> stats (aggregation over seeds) -> figures / tables (PNG+PDF, Markdown/LaTeX/CSV).
"""
