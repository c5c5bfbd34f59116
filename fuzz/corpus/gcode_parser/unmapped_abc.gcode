;A, B, C with the default options: errors (unsupported axis word)
G21
G1 X1 F600
M117 C is a parameter here
G1 X2 C5
