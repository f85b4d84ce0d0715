"""The live operator console: a local web page that shows a run as it records and answers its prompts (docs/console.md)."""
