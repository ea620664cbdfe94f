"""The belief-space OCP as compiled functions: its transcriptions (condensed, lifted), their
stage-wise derivatives, code generation and its cache, the points handed between solves, the
straight-line start, and the certificate that judges any plan from the problem's own functions."""
