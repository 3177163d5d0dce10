"""INAV over MSP (issue 47): the MSP client first; the backend, its simulator and the rest follow."""
