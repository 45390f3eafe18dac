"""Through-thickness refinement: enrichment state, extra nodes, refinement indicators."""
