#include "device/truth_table.hpp"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <sstream>

namespace icgt::sim {
namespace {

constexpr const char* kHeader =
    "tau_s,qw,qx,qy,qz,gyro_x_rad_s,gyro_y_rad_s,gyro_z_rad_s,accel_x_m_s2,accel_y_m_s2,accel_z_m_s2,"
    "lin_accel_x_m_s2,lin_accel_y_m_s2,lin_accel_z_m_s2,range_cm,range_valid";
constexpr std::size_t kColumns = 16;

}  // namespace

bool TruthTable::load(const std::string& path, std::string& error) {
  std::ifstream in(path);
  if (!in) {
    error = path + ": cannot open";
    return false;
  }
  std::string line;
  if (!std::getline(in, line) || line.rfind(kHeader, 0) != 0) {
    error = path + ":1: header is not the truth-table header of hil_sim/README.md";
    return false;
  }
  std::vector<TruthRow> rows;
  std::size_t line_no = 1;
  while (std::getline(in, line)) {
    ++line_no;
    if (line.empty()) continue;
    double v[kColumns];
    std::size_t n = 0;
    const char* p = line.c_str();
    while (n < kColumns) {
      char* end = nullptr;
      v[n] = std::strtod(p, &end);
      if (end == p) break;
      ++n;
      p = end;
      if (*p == ',') ++p;
    }
    if (n != kColumns || *p != '\0') {
      error = path + ":" + std::to_string(line_no) + ": expected " + std::to_string(kColumns) + " numbers";
      return false;
    }
    TruthRow r;
    r.tau_s = v[0];
    r.quat_wxyz = {v[1], v[2], v[3], v[4]};
    r.gyro_rad_s = {v[5], v[6], v[7]};
    r.accel_m_s2 = {v[8], v[9], v[10]};
    r.lin_accel_m_s2 = {v[11], v[12], v[13]};
    r.range_cm = v[14];
    r.range_valid = v[15] != 0.0;
    if (!rows.empty() && r.tau_s <= rows.back().tau_s) {
      error = path + ":" + std::to_string(line_no) + ": tau_s must increase";
      return false;
    }
    rows.push_back(r);
  }
  if (rows.empty()) {
    error = path + ": no rows";
    return false;
  }
  rows_ = std::move(rows);
  return true;
}

TruthRow TruthTable::at(double tau_s) const {
  if (rows_.empty()) return {};
  if (tau_s <= rows_.front().tau_s) return rows_.front();
  if (tau_s >= rows_.back().tau_s) return rows_.back();
  const auto it = std::upper_bound(rows_.begin(), rows_.end(), tau_s,
                                   [](double t, const TruthRow& r) { return t < r.tau_s; });
  const TruthRow& b = *it;
  const TruthRow& a = *(it - 1);
  const double f = (tau_s - a.tau_s) / (b.tau_s - a.tau_s);
  auto lerp = [f](double x, double y) { return x + (y - x) * f; };
  TruthRow r;
  r.tau_s = tau_s;
  const double dot = a.quat_wxyz[0] * b.quat_wxyz[0] + a.quat_wxyz[1] * b.quat_wxyz[1] +
                     a.quat_wxyz[2] * b.quat_wxyz[2] + a.quat_wxyz[3] * b.quat_wxyz[3];
  const double sign = dot < 0.0 ? -1.0 : 1.0;  // q and -q are the same rotation: take the short way
  double norm = 0.0;
  for (std::size_t i = 0; i < 4; ++i) {
    r.quat_wxyz[i] = lerp(a.quat_wxyz[i], sign * b.quat_wxyz[i]);
    norm += r.quat_wxyz[i] * r.quat_wxyz[i];
  }
  norm = std::sqrt(norm);
  for (auto& q : r.quat_wxyz) q /= norm;
  for (std::size_t i = 0; i < 3; ++i) {
    r.gyro_rad_s[i] = lerp(a.gyro_rad_s[i], b.gyro_rad_s[i]);
    r.accel_m_s2[i] = lerp(a.accel_m_s2[i], b.accel_m_s2[i]);
    r.lin_accel_m_s2[i] = lerp(a.lin_accel_m_s2[i], b.lin_accel_m_s2[i]);
  }
  // A return that appears or vanishes between rows switches at the nearer row, not blended.
  const TruthRow& nearer = f < 0.5 ? a : b;
  r.range_valid = nearer.range_valid;
  r.range_cm = a.range_valid && b.range_valid ? lerp(a.range_cm, b.range_cm) : nearer.range_cm;
  return r;
}

}  // namespace icgt::sim
