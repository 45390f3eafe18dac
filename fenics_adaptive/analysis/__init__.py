"""ESL-against-layerwise comparison tools and cost measurement."""
