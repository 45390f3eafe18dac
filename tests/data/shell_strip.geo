// A strip of quadrilaterals for [mesh] kind = "file" (units: mm): 40 x 20 in the plane z = 0,
// 8 x 4 cells, its short edges named "left" and "right" (the side faces loads and supports
// name), the surface "skin".
SetFactory("OpenCASCADE");
Rectangle(1) = {0, 0, 0, 40, 20};
Transfinite Curve{1, 3} = 9;
Transfinite Curve{2, 4} = 5;
Transfinite Surface{1};
Recombine Surface{1};
Physical Surface("skin") = {1};
Physical Curve("left") = {4};
Physical Curve("right") = {2};
