"""The diagnosis for people: text, report directory and figures (render), the HTML page (page)."""
