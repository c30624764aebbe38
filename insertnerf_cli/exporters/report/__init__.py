"""The pages `render` (index.html) and `eval` (report.html) write beside their outputs: static, offline (no script,
font or image from the internet; charts are inline SVG drawn here), linking only to files in their own folder by
relative paths, so the folder can be zipped and sent. Every string that comes from the user's files is escaped."""
