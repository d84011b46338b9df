/* Python's float semantics where C's differ, for the FCU's compiled twins of its Python
 * (uav_stack/fcu/_dynamics.c, uav_stack/fcu/_telemetry.c). */
#ifndef MRSWARM_PYFLOAT_H
#define MRSWARM_PYFLOAT_H

#include <math.h>

/* Python's float %: the result has the sign of the divisor. */
static inline double py_mod(double x, double y) {
    double m = fmod(x, y);
    if (m != 0.0) {
        if ((y < 0.0) != (m < 0.0)) m += y;
    } else {
        m = copysign(0.0, y);
    }
    return m;
}

#endif
