"""Paper figures and tables from the MLflow store: ``python -m sweep.report [--experiment] [--sweep] [--out]``.

load (MLflow -> pandas) -> stats (aggregation over seeds) -> figures / tables (PNG+PDF, Markdown/LaTeX/CSV).
"""
