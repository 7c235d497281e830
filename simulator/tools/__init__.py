"""Command-line tools: Table 7.1, the Fig. 7.3 sensitivity study, mesh-sequence export."""
