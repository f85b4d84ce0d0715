"""The live operator console: a local web page that shows a run as it records (plan, progress, frames,
readings, prompts) and answers its prompts or stops it (docs/console.md)."""
