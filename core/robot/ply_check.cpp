#include "ply_check.h"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <istream>
#include <streambuf>
#include <limits>
#include <optional>
#include <sstream>
#include <string_view>
#include <utility>
#include <vector>

namespace arref {
namespace {

enum class PlyType { kInt8, kUint8, kInt16, kUint16, kInt32, kUint32, kFloat32, kFloat64 };
enum class PlyFormat { kAscii, kLittleEndian, kBigEndian };

struct PlyProperty {
  std::string name;
  bool list = false;
  PlyType count = PlyType::kUint8;  // lists only
  PlyType item = PlyType::kFloat32;
};

struct PlyElement {
  std::string name;
  long long rows = 0;
  std::vector<PlyProperty> properties;
};

struct PlyHeader {
  PlyFormat format = PlyFormat::kAscii;
  std::vector<PlyElement> elements;
};

// What the checks need of each type, in PlyType's order: its two names, its size in a binary
// body, and the values it holds.
struct TypeInfo {
  std::string_view name, alias;
  int size;
  bool integer;
  double min, max;
};
constexpr std::array<TypeInfo, 8> kTypes = {{
    {"int8", "char", 1, true, -128.0, 127.0},
    {"uint8", "uchar", 1, true, 0.0, 255.0},
    {"int16", "short", 2, true, -32768.0, 32767.0},
    {"uint16", "ushort", 2, true, 0.0, 65535.0},
    {"int32", "int", 4, true, -2147483648.0, 2147483647.0},
    {"uint32", "uint", 4, true, 0.0, 4294967295.0},
    {"float32", "float", 4, false, -std::numeric_limits<float>::max(), std::numeric_limits<float>::max()},
    {"float64", "double", 8, false, -std::numeric_limits<double>::max(), std::numeric_limits<double>::max()},
}};

const TypeInfo& Info(PlyType t) { return kTypes[static_cast<std::size_t>(t)]; }

std::optional<PlyType> ParseType(const std::string& name) {
  for (std::size_t i = 0; i < kTypes.size(); ++i)
    if (kTypes[i].name == name || kTypes[i].alias == name) return static_cast<PlyType>(i);
  return std::nullopt;
}

const char* TypeName(PlyType t) { return Info(t).name.data(); }
int SizeOf(PlyType t) { return Info(t).size; }
bool IsInteger(PlyType t) { return Info(t).integer; }

// Whether a value read as a double is one the type holds (finite, integral for integer types).
bool Fits(PlyType t, double v) {
  const TypeInfo& info = Info(t);
  return std::isfinite(v) && (!info.integer || v == std::floor(v)) && v >= info.min && v <= info.max;
}

class HeaderReader {
 public:
  explicit HeaderReader(std::istream& in) : in_(in) {}
  Result<PlyHeader> Read();

 private:
  bool Next() {
    if (!std::getline(in_, line_)) return false;
    if (!line_.empty() && line_.back() == '\r') line_.pop_back();
    return true;
  }
  // The line as shown in the error, control characters as '?' (a log must stay readable).
  Status Bad(int n, const std::string& why) const {
    std::string shown = line_.substr(0, 60);
    for (char& c : shown)
      if (static_cast<unsigned char>(c) < 0x20) c = '?';
    return Status::IoError(fmt::format("PLY header line {} ('{}'): {}", n, shown, why));
  }
  Status Element(int n, const std::vector<std::string>& words, PlyHeader* header) const;
  Status Property(int n, const std::vector<std::string>& words, PlyHeader* header) const;

  std::istream& in_;
  std::string line_;
};

// A header line's words; none may hold a control character (a binary body run into the header).
std::optional<std::vector<std::string>> Words(const std::string& line) {
  for (const char c : line)
    if (static_cast<unsigned char>(c) < 0x20 && c != '\t') return std::nullopt;
  std::istringstream in(line);
  std::vector<std::string> words;
  for (std::string w; in >> w;) words.push_back(std::move(w));
  return words;
}

// An element's or property's name starts with a letter or '_'. Assimp 5.2 read the row count of
// an element named with twenty digits before its letters ('element 8888...face 9') as a number
// that overflowed, and reserved gigabytes for it (tests/fuzz/regressions/mesh).
bool IsName(const std::string& word) {
  return !word.empty() && (std::isalpha(static_cast<unsigned char>(word.front())) || word.front() == '_');
}

Status HeaderReader::Element(int n, const std::vector<std::string>& words, PlyHeader* header) const {
  PlyElement e;
  if (words.size() != 3) return Bad(n, "expected 'element NAME COUNT'");
  if (!IsName(words[1])) return Bad(n, "an element's name must start with a letter or '_'");
  e.name = words[1];
  const char* end = words[2].data() + words[2].size();
  const auto [ptr, ec] = std::from_chars(words[2].data(), end, e.rows);
  if (ec != std::errc() || ptr != end || e.rows < 0) return Bad(n, "expected 'element NAME COUNT'");
  // Assimp corrupted its heap on a file with two 'vertex' elements (tests/fuzz/regressions/mesh).
  for (const PlyElement& other : header->elements)
    if (other.name == e.name) return Bad(n, "a second element '" + e.name + "'");
  header->elements.push_back(std::move(e));
  return Status::Ok();
}

Status HeaderReader::Property(int n, const std::vector<std::string>& words, PlyHeader* header) const {
  if (header->elements.empty()) return Bad(n, "a property before any element");
  const bool list = words.size() > 1 && words[1] == "list";
  if (words.size() != (list ? 5u : 3u))
    return Bad(n, "expected 'property TYPE NAME' or 'property list COUNT_TYPE TYPE NAME'");
  PlyElement& element = header->elements.back();
  PlyProperty p;
  if (!IsName(words.back())) return Bad(n, "a property's name must start with a letter or '_'");
  p.name = words.back();
  for (const PlyProperty& other : element.properties)
    if (other.name == p.name) return Bad(n, "a second property '" + p.name + "' in element '" + element.name + "'");
  if (list) {
    const auto c = ParseType(words[2]);
    if (!c || !IsInteger(*c)) return Bad(n, "a list's count type must be an integer type, not '" + words[2] + "'");
    p.list = true, p.count = *c;
  }
  const auto t = ParseType(words[list ? 3 : 1]);
  if (!t) return Bad(n, "unknown type '" + words[list ? 3 : 1] + "'");
  p.item = *t;
  element.properties.push_back(std::move(p));
  return Status::Ok();
}

// What a mesh file needs of its header beyond the format: vertices with scalar x, y and z.
Status CheckMeshElements(const PlyHeader& header) {
  for (const PlyElement& e : header.elements) {
    if (e.name != "vertex") continue;
    for (const char* axis : {"x", "y", "z"}) {
      const auto it = std::find_if(e.properties.begin(), e.properties.end(),
                                   [&](const PlyProperty& p) { return p.name == axis; });
      if (it == e.properties.end() || it->list)
        return Status::IoError(fmt::format("PLY header: element 'vertex' has no scalar property '{}'", axis));
    }
    return Status::Ok();
  }
  return Status::IoError("PLY header: no element 'vertex'");
}

Result<PlyHeader> HeaderReader::Read() {
  if (!Next() || line_ != "ply") return Status::IoError("not a PLY file: the first line is not 'ply'");
  PlyHeader header;
  bool format = false;
  for (int n = 2; n < 100000 && Next(); ++n) {
    const auto words = Words(line_);
    if (!words) return Bad(n, "a control character in the header");
    const std::string key = words->empty() ? "" : words->front();
    const bool last_has_no_property = !header.elements.empty() && header.elements.back().properties.empty() &&
                                      header.elements.back().rows > 0;
    if (key == "comment" || key == "obj_info") continue;
    if (key == "end_header") {
      if (!format) return Bad(n, "no format line before end_header");
      if (last_has_no_property) return Bad(n, "the last element has no property");
      ARREF_RETURN_IF_ERROR(CheckMeshElements(header));
      return header;
    }
    if (key == "format") {
      const std::string kind = words->size() == 3 ? (*words)[1] : "";
      if (format || words->size() != 3 || (*words)[2] != "1.0" ||
          (kind != "ascii" && kind != "binary_little_endian" && kind != "binary_big_endian"))
        return Bad(n, "expected one 'format ascii|binary_little_endian|binary_big_endian 1.0'");
      header.format = kind == "ascii" ? PlyFormat::kAscii
                      : kind == "binary_little_endian" ? PlyFormat::kLittleEndian
                                                       : PlyFormat::kBigEndian;
      format = true;
    } else if (key == "element") {
      if (last_has_no_property) return Bad(n, "the element before has no property");
      ARREF_RETURN_IF_ERROR(Element(n, *words, &header));
    } else if (key == "property") {
      ARREF_RETURN_IF_ERROR(Property(n, *words, &header));
    } else {
      return Bad(n, "not a PLY header keyword");
    }
  }
  return Status::IoError("PLY header has no end_header line");
}

// Reads the body's values one at a time, as text or as binary of either byte order. A text row
// is one line: assimp reads ASCII bodies line by line, so values that wrap onto the next line
// shift every row after them (an ASCII face count read from a vertex line made it allocate
// 2.6 GB; tests/fuzz/regressions/mesh).
class ValueReader {
 public:
  ValueReader(std::istream& in, PlyFormat format) : in_(in), format_(format) {}
  bool BeginRow();  // false at the end of the file
  // The next value of type t; false at the end of the row (text) or file (binary), with token()
  // empty, or on a value the type cannot hold (what was read is in token()).
  bool Next(PlyType t, double* value);
  bool RowDone();  // no value left on the row's line
  const std::string& token() const { return token_; }

 private:
  bool NextBinary(PlyType t, double* value);

  std::istream& in_;
  PlyFormat format_;
  std::istringstream row_;
  std::string token_;
};

bool ValueReader::BeginRow() {
  if (format_ != PlyFormat::kAscii) return in_.peek() != std::char_traits<char>::eof();
  std::string line;
  if (!std::getline(in_, line)) return false;
  row_.clear();
  row_.str(std::move(line));  // the line's buffer moves into the stream: no copy per row
  return true;
}

bool ValueReader::RowDone() {
  if (format_ != PlyFormat::kAscii) return true;
  token_.clear();
  return !(row_ >> token_);
}

bool ValueReader::Next(PlyType t, double* value) {
  if (format_ != PlyFormat::kAscii) return NextBinary(t, value);
  token_.clear();
  if (!(row_ >> token_)) return false;
  const char* end = token_.data() + token_.size();
  const auto [ptr, ec] = std::from_chars(token_.data(), end, *value);
  return ec == std::errc() && ptr == end && Fits(t, *value);
}

bool ValueReader::NextBinary(PlyType t, double* value) {
  std::array<unsigned char, 8> b{};
  const int size = SizeOf(t);
  token_.clear();
  if (!in_.read(reinterpret_cast<char*>(b.data()), size)) return false;
  if ((format_ == PlyFormat::kBigEndian) == (std::endian::native == std::endian::little))
    std::reverse(b.begin(), b.begin() + size);
  std::uint64_t bits = 0;
  std::memcpy(&bits, b.data(), static_cast<std::size_t>(size));  // native order now
  switch (t) {
    case PlyType::kInt8: *value = static_cast<std::int8_t>(bits); break;
    case PlyType::kUint8: *value = static_cast<std::uint8_t>(bits); break;
    case PlyType::kInt16: *value = static_cast<std::int16_t>(bits); break;
    case PlyType::kUint16: *value = static_cast<std::uint16_t>(bits); break;
    case PlyType::kInt32: *value = static_cast<std::int32_t>(bits); break;
    case PlyType::kUint32: *value = static_cast<std::uint32_t>(bits); break;
    case PlyType::kFloat32: *value = std::bit_cast<float>(static_cast<std::uint32_t>(bits)); break;
    case PlyType::kFloat64: *value = std::bit_cast<double>(bits); break;
  }
  if (Fits(t, *value)) return true;
  // Shown only in the error: the bytes in native order.
  for (int i = 0; i < size; ++i) token_ += fmt::format("{:02x}", b[static_cast<std::size_t>(i)]);
  return false;
}

// Every row of every element, value by value. Each value read takes at least one byte, so a
// list's count cannot make this loop outlast the file.
Status CheckBody(std::istream& in, const PlyHeader& header) {
  const bool text = header.format == PlyFormat::kAscii;
  ValueReader reader(in, header.format);
  for (const PlyElement& e : header.elements)
    for (long long row = 0; row < e.rows; ++row) {
      // Formatted only for an error: this loop runs once a row of files with millions of rows.
      const auto where = [&] { return fmt::format("element '{}' row {}", e.name, row + 1); };
      const auto ends = [&] { return Status::IoError(fmt::format("PLY body ends in {} of {}", where(), e.rows)); };
      if (!reader.BeginRow()) return ends();
      for (std::size_t k = 0; k < e.properties.size(); ++k) {
        const PlyProperty& p = e.properties[k];
        const auto fault = [&](PlyType t, const char* what) {
          if (!reader.token().empty())
            return Status::IoError(fmt::format("PLY body: {} property {}: {} '{}' is not a {}", where(), k + 1, what,
                                               reader.token().substr(0, 40), TypeName(t)));
          if (!text) return ends();
          return Status::IoError(fmt::format("PLY body: {}: the line ends before property {} (one row a line)", where(), k + 1));
        };
        double v = 0;
        long long items = 1;
        if (p.list) {
          if (!reader.Next(p.count, &v)) return fault(p.count, "list count");
          items = static_cast<long long>(v);
        }
        for (long long i = 0; i < items; ++i)
          if (!reader.Next(p.item, &v)) return fault(p.item, "value");
      }
      if (!reader.RowDone())
        return Status::IoError(fmt::format("PLY body: {}: '{}' beyond its {} properties (one row a line)", where(),
                                           reader.token().substr(0, 40), e.properties.size()));
    }
  return Status::Ok();
}

// An istream over bytes held elsewhere, read in place (an istringstream would copy a mesh of
// tens of MB).
class BytesBuffer : public std::streambuf {
 public:
  explicit BytesBuffer(std::string_view bytes) {
    char* p = const_cast<char*>(bytes.data());  // only read: the get area wants char*
    setg(p, p, p + bytes.size());
  }
};

}  // namespace

Status CheckPly(std::string_view bytes) {
  BytesBuffer buffer(bytes);
  std::istream in(&buffer);
  HeaderReader header_reader(in);
  ARREF_ASSIGN_OR_RETURN(const PlyHeader header, header_reader.Read());
  return CheckBody(in, header);
}

}  // namespace arref
