"""What labctl writes for people and other tools: the HTML report, the comparison and point-cloud files."""
