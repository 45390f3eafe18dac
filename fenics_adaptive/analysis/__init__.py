"""Studies and references: the demos' runs as config variants, the LEFM reference, ESL-against-
layerwise comparison tools, cost measurement."""
