/**
 * Configuration.h (test fixture: a build with Marlin's CNC G-code switches, issue 21)
 */
#pragma once
#define CONFIGURATION_H_VERSION 02010204
#define MOTHERBOARD BOARD_RAMPS_14_EFB
#define X_BED_SIZE 250
#define Y_BED_SIZE 210
#define X_MIN_POS 0
#define Y_MIN_POS -4
#define Z_MIN_POS 0
#define X_MAX_POS X_BED_SIZE + 5
#define Y_MAX_POS (Y_BED_SIZE + 2.5)
#define Z_MAX_POS 210
#define MIN_SOFTWARE_ENDSTOPS
#define MAX_SOFTWARE_ENDSTOPS
//#define DISTINCT_E_FACTORS
#define DEFAULT_AXIS_STEPS_PER_UNIT   { 100, 100, 400, 280 }
#define DEFAULT_MAX_FEEDRATE          { 200, 200, 12, 120 }
//#define LIMITED_MAX_FR_EDITING
#define DEFAULT_MAX_ACCELERATION      { 1000, 1000, 200, 5000 }
#define DEFAULT_ACCELERATION          1250    // X, Y, Z and E acceleration for printing moves
#define DEFAULT_RETRACT_ACCELERATION  1250    // E acceleration for retracts
#define DEFAULT_TRAVEL_ACCELERATION   1500    // X, Y, Z acceleration for travel (non printing) moves
#define CLASSIC_JERK
#if ENABLED(CLASSIC_JERK)
  #define DEFAULT_XJERK  8.0
  #define DEFAULT_YJERK  8.0
  #define DEFAULT_ZJERK  0.4
  //#define LIMITED_JERK_EDITING
#endif
#define DEFAULT_EJERK    4.5  // May be used by Linear Advance
#if DISABLED(CLASSIC_JERK)
  #define JUNCTION_DEVIATION_MM 0.013 // (mm) Distance from real junction edge
  #define JD_HANDLE_SMALL_SEGMENTS
#endif
//#define S_CURVE_ACCELERATION

// @section units

//
// G20/G21 Inch mode support
//
#define INCH_MODE_SUPPORT
