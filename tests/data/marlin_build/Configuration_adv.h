#pragma once
#define CONFIGURATION_ADV_H_VERSION 02010204
#define DEFAULT_MINIMUMFEEDRATE       0.0     // (mm/s) Minimum feedrate. Set with M205 S.
#define DEFAULT_MINTRAVELFEEDRATE     0.0
#define DEFAULT_MINSEGMENTTIME        20000   // (µs) Set with M205 B.
#define SLOWDOWN
#if ENABLED(SLOWDOWN)
  #define SLOWDOWN_DIVISOR 2
#endif
#define MINIMUM_PLANNER_SPEED 0.05 // (mm/s)
//#define LIN_ADVANCE
#if ENABLED(LIN_ADVANCE)
  #define ADVANCE_K 0.22
#endif
#define MIN_STEPS_PER_SEGMENT 6
#if ALL(HAS_MEDIA, DIRECT_STEPPING)
  #define BLOCK_BUFFER_SIZE  8
#elif HAS_MEDIA
  #define BLOCK_BUFFER_SIZE 16
#else
  #define BLOCK_BUFFER_SIZE 16
#endif
#define ARC_SUPPORT                   // Requires ~3226 bytes
#if ENABLED(ARC_SUPPORT)
  #define MIN_ARC_SEGMENT_MM      0.1 // (mm) Minimum length of each arc segment
  #define MAX_ARC_SEGMENT_MM      1.0 // (mm) Maximum length of each arc segment
  #define MIN_CIRCLE_SEGMENTS    72
  //#define ARC_SEGMENTS_PER_SEC 50
  #define N_ARC_CORRECTION       25
  //#define ARC_P_CIRCLES
  #define CNC_WORKSPACE_PLANES      // Allow G2/G3 to operate in XY, ZX, or YZ planes
#endif
//#define BEZIER_CURVE_SUPPORT        // Requires ~2666 bytes
//#define G38_PROBE_TARGET
//#define CNC_COORDINATE_SYSTEMS
//#define SAVED_POSITIONS 1         // Each saved position slot costs 12 bytes

/**
 * CNC G-code options
 */
//#define PAREN_COMMENTS      // Support for parentheses-delimited comments
#define GCODE_MOTION_MODES  // Remember the motion mode (G0 G1 G2 G3 G5 G38.X) and apply for X Y Z E F, etc.
//#define INPUT_SHAPING_X
//#define FT_MOTION
