"""Critical samples (the paper's Section IV): models on the fixed Halton graph (``models``) and the
adapter from problems to their inputs (``data``)."""
