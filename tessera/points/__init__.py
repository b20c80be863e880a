"""Point clouds (issue 36): what render nodes and the coordinator both compute of them."""
