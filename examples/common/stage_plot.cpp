#include "stage_plot.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "octofuse/ports/host/atomic_file.hpp"

namespace octofuse::plot {

bool write_stacked_svg(const std::string& path, const std::string& title,
                       const std::vector<StageSeries>& series) {
  if (series.empty()) return false;
  const std::size_t frames = series.front().values.size();
  for (const StageSeries& s : series) {
    if (s.values.size() != frames) return false;
  }
  std::vector<double> top(frames, 0.0);
  for (const StageSeries& s : series) {
    for (std::size_t i = 0; i < frames; ++i) top[i] += std::max(0.0, s.values[i]);
  }
  double y_max = 1.0;
  for (double v : top) y_max = std::max(y_max, v);
  // Round the axis up to 1, 2 or 5 times a power of ten.
  const double magnitude = std::pow(10.0, std::floor(std::log10(y_max)));
  double axis_max = magnitude;
  for (double m : {1.0, 2.0, 5.0, 10.0}) {
    if (m * magnitude >= y_max) {
      axis_max = m * magnitude;
      break;
    }
  }

  const double width = 900.0, height = 420.0, left = 60.0, right = 150.0, top_margin = 40.0,
               bottom = 50.0;
  const double plot_w = width - left - right, plot_h = height - top_margin - bottom;
  auto x_of = [&](std::size_t i) {
    return left +
           (frames > 1 ? plot_w * static_cast<double>(i) / static_cast<double>(frames - 1) : 0.0);
  };
  auto y_of = [&](double v) { return top_margin + plot_h * (1.0 - v / axis_max); };

  // Through a temporary renamed into place: a crash leaves the previous plot or this one, whole.
  host::AtomicFile out;
  if (!out.open(path.c_str()).ok()) return false;
  std::FILE* f = out.file();
  std::fprintf(f,
               "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"%.0f\" height=\"%.0f\" "
               "font-family=\"sans-serif\" font-size=\"12\">\n<rect width=\"100%%\" "
               "height=\"100%%\" fill=\"white\"/>\n",
               width, height);
  std::fprintf(f, "<text x=\"%.0f\" y=\"24\" font-size=\"15\">%s</text>\n", left, title.c_str());

  std::vector<double> lower(frames, 0.0);
  int legend_row = 0;
  for (const StageSeries& s : series) {
    std::fprintf(f, "<polygon fill=\"%s\" fill-opacity=\"0.85\" points=\"", s.colour.c_str());
    for (std::size_t i = 0; i < frames; ++i) {
      std::fprintf(f, "%.1f,%.1f ", x_of(i), y_of(lower[i] + std::max(0.0, s.values[i])));
    }
    for (std::size_t i = frames; i-- > 0;) std::fprintf(f, "%.1f,%.1f ", x_of(i), y_of(lower[i]));
    std::fprintf(f, "\"/>\n");
    for (std::size_t i = 0; i < frames; ++i) lower[i] += std::max(0.0, s.values[i]);
    const double ly = top_margin + 20.0 * legend_row++;
    std::fprintf(f,
                 "<rect x=\"%.0f\" y=\"%.0f\" width=\"14\" height=\"14\" fill=\"%s\"/><text "
                 "x=\"%.0f\" y=\"%.0f\">%s</text>\n",
                 width - right + 15.0, ly, s.colour.c_str(), width - right + 35.0, ly + 12.0,
                 s.name.c_str());
  }
  // Axes with five ticks.
  std::fprintf(f,
               "<line x1=\"%.0f\" y1=\"%.0f\" x2=\"%.0f\" y2=\"%.0f\" stroke=\"black\"/>\n"
               "<line x1=\"%.0f\" y1=\"%.0f\" x2=\"%.0f\" y2=\"%.0f\" stroke=\"black\"/>\n",
               left, top_margin, left, top_margin + plot_h, left, top_margin + plot_h,
               left + plot_w, top_margin + plot_h);
  for (int t = 0; t <= 5; ++t) {
    const double v = axis_max * t / 5.0;
    std::fprintf(f,
                 "<text x=\"%.0f\" y=\"%.1f\" text-anchor=\"end\">%g</text><line x1=\"%.0f\" "
                 "y1=\"%.1f\" x2=\"%.0f\" y2=\"%.1f\" stroke=\"#ddd\"/>\n",
                 left - 6.0, y_of(v) + 4.0, v, left, y_of(v), left + plot_w, y_of(v));
    const std::size_t frame = frames > 1 ? (frames - 1) * static_cast<std::size_t>(t) / 5 : 0;
    std::fprintf(f, "<text x=\"%.1f\" y=\"%.0f\" text-anchor=\"middle\">%zu</text>\n", x_of(frame),
                 top_margin + plot_h + 18.0, frame);
  }
  std::fprintf(f,
               "<text x=\"%.0f\" y=\"%.0f\" text-anchor=\"middle\">frame</text>\n<text "
               "transform=\"translate(16,%.0f) rotate(-90)\" text-anchor=\"middle\">time per "
               "frame (ms)</text>\n</svg>\n",
               left + plot_w / 2.0, height - 10.0, top_margin + plot_h / 2.0);
  return out.commit().ok();  // fails on any earlier stream error too
}

}  // namespace octofuse::plot
