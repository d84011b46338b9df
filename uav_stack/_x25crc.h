/* MAVLink's CRC (X.25, CRC-16/MCRF4XX) as pymavlink's x25crc computes it, for every compiled
 * module that frames or checks MAVLink (uav_stack/_mavcodec.c, uav_stack/fcu/_telemetry.c). */
#ifndef MRSWARM_X25CRC_H
#define MRSWARM_X25CRC_H

#include <stdint.h>

static inline uint16_t crc_accumulate(uint16_t crc, const unsigned char *p, Py_ssize_t n) {
    for (Py_ssize_t i = 0; i < n; i++) {
        uint8_t tmp = p[i] ^ (uint8_t)(crc & 0xFF);
        tmp ^= (uint8_t)(tmp << 4);
        crc = (uint16_t)((crc >> 8) ^ ((uint16_t)tmp << 8) ^ ((uint16_t)tmp << 3) ^ (tmp >> 4));
    }
    return crc;
}

#endif
