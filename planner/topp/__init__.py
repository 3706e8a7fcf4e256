"""TOPP-RA, toppra's algorithm with its bookkeeping done once and its LPs compiled: the rows (``rows``), the
seidel LPs (``seidel``), the two passes (``passes``) and the algorithm object (``lean.LeanTOPPRA``)."""
