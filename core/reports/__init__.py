"""Reports a person opens: one HTML page per unit, and the control charts of a batch.  Self-contained
(plotly.js from the installed plotly package is embedded, never a CDN): a line PC has no internet."""
