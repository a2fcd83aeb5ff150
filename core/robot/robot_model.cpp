// URDF robot model: urdfdom for parsing, assimp (mesh_loading.cpp) for link meshes.
#include "arref/robot/robot_model.h"

#include "arref/base/files.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <tinyxml.h>
#include <urdf_parser/urdf_parser.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <numbers>

namespace arref {
namespace {

Iso3 ToIso(const urdf::Pose& pose) {
  Quat q(pose.rotation.w, pose.rotation.x, pose.rotation.y, pose.rotation.z);
  return MakePose(Vec3(pose.position.x, pose.position.y, pose.position.z), q);
}

TriangleMesh BoxMesh(const Vec3& size) {
  TriangleMesh m;
  const Vec3f h = (size / 2).cast<float>();
  for (int i = 0; i < 8; ++i)
    m.vertices.emplace_back(i & 1 ? h.x() : -h.x(), i & 2 ? h.y() : -h.y(), i & 4 ? h.z() : -h.z());
  // Counter-clockwise seen from outside.
  m.triangles = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                 {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
  return m;
}

// Cylinder along z, centred at the origin (URDF convention); 48 sides keep the facet error
// below 0.3 % of the radius.
TriangleMesh CylinderMesh(double radius, double length, int sides = 48) {
  TriangleMesh m;
  const float h = static_cast<float>(length / 2);
  for (int i = 0; i < sides; ++i) {
    const double a = 2 * std::numbers::pi * i / sides;
    const float x = static_cast<float>(radius * std::cos(a)), y = static_cast<float>(radius * std::sin(a));
    m.vertices.emplace_back(x, y, -h);
    m.vertices.emplace_back(x, y, h);
  }
  const auto bottom = static_cast<std::uint32_t>(m.vertices.size());
  m.vertices.emplace_back(0, 0, -h);
  m.vertices.emplace_back(0, 0, h);
  for (std::uint32_t i = 0; i < static_cast<std::uint32_t>(sides); ++i) {
    const std::uint32_t j = (i + 1) % sides;
    m.triangles.push_back({2 * i, 2 * j, 2 * i + 1});
    m.triangles.push_back({2 * j, 2 * j + 1, 2 * i + 1});
    m.triangles.push_back({bottom, 2 * j, 2 * i});
    m.triangles.push_back({bottom + 1, 2 * i + 1, 2 * j + 1});
  }
  return m;
}

TriangleMesh SphereMesh(double radius, int rings = 16, int segments = 32) {
  TriangleMesh m;
  for (int r = 0; r <= rings; ++r) {
    const double theta = std::numbers::pi * r / rings;
    for (int s = 0; s < segments; ++s) {
      const double phi = 2 * std::numbers::pi * s / segments;
      m.vertices.emplace_back(Vec3(radius * std::sin(theta) * std::cos(phi), radius * std::sin(theta) * std::sin(phi),
                                   radius * std::cos(theta)).cast<float>());
    }
  }
  auto at = [segments](int r, int s) { return static_cast<std::uint32_t>(r * segments + (s % segments)); };
  for (int r = 0; r < rings; ++r)
    for (int s = 0; s < segments; ++s) {
      if (r > 0) m.triangles.push_back({at(r, s), at(r + 1, s), at(r, s + 1)});
      if (r + 1 < rings) m.triangles.push_back({at(r, s + 1), at(r + 1, s), at(r + 1, s + 1)});
    }
  return m;
}

JointType ToJointType(int urdf_type) {
  switch (urdf_type) {
    case urdf::Joint::REVOLUTE: return JointType::kRevolute;
    case urdf::Joint::CONTINUOUS: return JointType::kContinuous;
    case urdf::Joint::PRISMATIC: return JointType::kPrismatic;
    default: return JointType::kFixed;  // fixed; floating and planar are treated as rigid
  }
}

// TinyXML (which urdfdom parses with) reads a UTF-8 lead byte's whole sequence without looking
// for the end of the text: a sequence cut short by the end of the file makes it read past the
// buffer (heap-buffer-overflow, found by tests/fuzz/urdf_fuzz.cpp), and a NUL byte silently ends
// the document early. XML without an encoding declaration is UTF-8 (XML 1.0, 4.3.3), so refuse
// anything else before TinyXML sees it, naming the first bad byte.
Status CheckUtf8Text(const std::string& text) {
  const auto* bytes = reinterpret_cast<const unsigned char*>(text.data());
  for (std::size_t i = 0; i < text.size();) {
    const unsigned char lead = bytes[i];
    if (lead == 0) return Status::InvalidArgument(fmt::format("not a valid URDF: byte {} is NUL", i));
    // Sequence length from the lead byte (RFC 3629: C0, C1 and F5-FF never appear).
    const std::size_t length = lead < 0x80 ? 1 : lead >= 0xC2 && lead <= 0xDF ? 2 : lead >= 0xE0 && lead <= 0xEF ? 3
                                           : lead >= 0xF0 && lead <= 0xF4 ? 4 : 0;
    bool ok = length > 0 && i + length <= text.size();
    for (std::size_t k = 1; ok && k < length; ++k) ok = (bytes[i + k] & 0xC0) == 0x80;
    if (!ok)
      return Status::InvalidArgument(
          fmt::format("not a valid URDF: byte {} (0x{:02X}) starts no complete UTF-8 character (save it as UTF-8)", i,
                      lead));
    i += length;
  }
  return Status::Ok();
}

// URDF joints must form a tree. urdfdom links a parent to its children with owning pointers
// before it checks the tree, so joints that loop (a -> b -> a), or a link with two parents, leave
// a cycle it never frees, and a loop beside the tree is even accepted with links that have no
// pose (found by tests/fuzz/urdf_fuzz.cpp, as leaks). This reads the joints first (tinyxml, as
// urdfdom does) and refuses such files; everything else is left to urdfdom.
Status CheckJointTree(const std::string& urdf_xml) {
  TiXmlDocument doc;
  doc.Parse(urdf_xml.c_str());
  const TiXmlElement* robot = doc.Error() ? nullptr : doc.FirstChildElement("robot");
  if (!robot) return Status::Ok();  // urdfdom says what is wrong
  std::map<std::string, std::string> parent_of;  // child link -> parent link
  for (const TiXmlElement* j = robot->FirstChildElement("joint"); j; j = j->NextSiblingElement("joint")) {
    const TiXmlElement* parent = j->FirstChildElement("parent");
    const TiXmlElement* child = j->FirstChildElement("child");
    const char* parent_link = parent ? parent->Attribute("link") : nullptr;
    const char* child_link = child ? child->Attribute("link") : nullptr;
    if (!parent_link || !child_link) continue;
    if (!parent_of.emplace(child_link, parent_link).second)
      return Status::InvalidArgument(fmt::format("not a valid URDF: link '{}' is the child of two joints", child_link));
  }
  for (const auto& [link, parent] : parent_of) {
    std::string at = parent;
    for (std::size_t steps = 0; steps <= parent_of.size(); ++steps) {
      if (at == link)
        return Status::InvalidArgument(fmt::format("not a valid URDF: the joints above link '{}' form a loop", link));
      const auto up = parent_of.find(at);
      if (up == parent_of.end()) break;
      at = up->second;
    }
  }
  return Status::Ok();
}

}  // namespace

struct RobotModel::Impl {
  urdf::ModelInterfaceSharedPtr urdf;
  std::map<std::string, TriangleMesh> link_meshes;  // geometry in each link's frame
  std::vector<JointInfo> joints;                    // every non-fixed joint, tree order
  std::map<std::string, std::size_t> joint_index;

  Status LoadGeometry(const std::string& urdf_dir, const RobotLoadOptions& options);
  Result<TriangleMesh> GeometryMesh(const urdf::Geometry& geometry, const std::string& link,
                                    const std::string& urdf_dir, const RobotLoadOptions& options) const;
  void CollectJoints(const urdf::Link& link);
  void AddLinkPoses(const urdf::Link& link, const Iso3& T_root_link, const JointValues& values,
                    std::map<std::string, Iso3>* poses) const;
};

Result<TriangleMesh> RobotModel::Impl::GeometryMesh(const urdf::Geometry& geometry, const std::string& link,
                                                    const std::string& urdf_dir,
                                                    const RobotLoadOptions& options) const {
  switch (geometry.type) {
    case urdf::Geometry::BOX: {
      const auto& d = static_cast<const urdf::Box&>(geometry).dim;
      return BoxMesh(Vec3(d.x, d.y, d.z));
    }
    case urdf::Geometry::CYLINDER: {
      const auto& c = static_cast<const urdf::Cylinder&>(geometry);
      return CylinderMesh(c.radius, c.length);
    }
    case urdf::Geometry::SPHERE:
      return SphereMesh(static_cast<const urdf::Sphere&>(geometry).radius);
    case urdf::Geometry::MESH: {
      const auto& m = static_cast<const urdf::Mesh&>(geometry);
      auto path = ResolveMeshUri(m.filename, urdf_dir, options.package_path);
      if (!path.ok()) return path.status().WithContext("link '" + link + "'");
      auto mesh = LoadMeshFile(*path);
      if (!mesh.ok()) return mesh.status().WithContext("link '" + link + "'");
      const Eigen::Vector3f scale(m.scale.x, m.scale.y, m.scale.z);
      for (auto& v : mesh->vertices) v = v.cwiseProduct(scale);
      if (scale.prod() < 0)  // a mirroring scale turns the surface inside out
        for (auto& t : mesh->triangles) std::swap(t[1], t[2]);
      return mesh;
    }
  }
  return Status::InvalidArgument("link '" + link + "': unsupported geometry type");
}

Status RobotModel::Impl::LoadGeometry(const std::string& urdf_dir, const RobotLoadOptions& options) {
  for (const auto& entry : urdf->links_) {
    // Not a structured binding: clang 14 (the fuzz build) cannot capture those in a lambda.
    const std::string& name = entry.first;
    const urdf::LinkSharedPtr& link = entry.second;
    TriangleMesh mesh;
    auto add = [&](const urdf::GeometrySharedPtr& geometry, const urdf::Pose& origin) -> Status {
      if (!geometry) return Status::Ok();
      ARREF_ASSIGN_OR_RETURN(const TriangleMesh part, GeometryMesh(*geometry, name, urdf_dir, options));
      mesh.Append(part, ToIso(origin));
      return Status::Ok();
    };
    if (options.geometry == GeometryKind::kVisual) {
      for (const auto& visual : link->visual_array) ARREF_RETURN_IF_ERROR(add(visual->geometry, visual->origin));
    } else {
      for (const auto& collision : link->collision_array)
        ARREF_RETURN_IF_ERROR(add(collision->geometry, collision->origin));
    }
    if (!mesh.empty()) link_meshes.emplace(name, std::move(mesh));
  }
  return Status::Ok();
}

void RobotModel::Impl::CollectJoints(const urdf::Link& link) {
  for (const auto& joint : link.child_joints) {
    const JointType type = ToJointType(joint->type);
    if (type != JointType::kFixed) {
      JointInfo info;
      info.name = joint->name;
      info.type = type;
      if (joint->limits && type != JointType::kContinuous) {
        info.lower = joint->limits->lower;
        info.upper = joint->limits->upper;
        info.has_limits = info.upper > info.lower;
      }
      if (joint->mimic) {
        info.mimic_of = joint->mimic->joint_name;
        info.mimic_multiplier = joint->mimic->multiplier;
        info.mimic_offset = joint->mimic->offset;
      }
      joint_index[info.name] = joints.size();
      joints.push_back(info);
    }
    if (auto child = urdf->getLink(joint->child_link_name)) CollectJoints(*child);
  }
}

void RobotModel::Impl::AddLinkPoses(const urdf::Link& link, const Iso3& T_root_link, const JointValues& values,
                                    std::map<std::string, Iso3>* poses) const {
  (*poses)[link.name] = T_root_link;
  for (const auto& joint : link.child_joints) {
    Iso3 T_parent_child = ToIso(joint->parent_to_joint_origin_transform);
    const JointType type = ToJointType(joint->type);
    if (type != JointType::kFixed) {
      const double q = values.at(joint->name);
      const Vec3 axis = Vec3(joint->axis.x, joint->axis.y, joint->axis.z).normalized();
      if (type == JointType::kPrismatic)
        T_parent_child.translate(q * axis);
      else
        T_parent_child.rotate(Eigen::AngleAxisd(q, axis));
    }
    if (auto child = urdf->getLink(joint->child_link_name))
      AddLinkPoses(*child, T_root_link * T_parent_child, values, poses);
  }
}

RobotModel::RobotModel(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
RobotModel::RobotModel(RobotModel&&) noexcept = default;
RobotModel& RobotModel::operator=(RobotModel&&) noexcept = default;
RobotModel::~RobotModel() = default;

Result<RobotModel> RobotModel::Load(const std::string& urdf_path, const RobotLoadOptions& options) {
  const std::optional<std::string> text = ReadWholeFile(urdf_path);
  if (!text) return Status::NotFound("URDF not found or unreadable: " + urdf_path);
  const std::string dir = std::filesystem::absolute(urdf_path).parent_path().string();
  auto model = FromString(*text, dir, options);
  if (!model.ok()) return model.status().WithContext("loading robot " + urdf_path);
  return model;
}

Result<RobotModel> RobotModel::FromString(const std::string& urdf_xml, const std::string& base_dir,
                                          const RobotLoadOptions& options) {
  ARREF_RETURN_IF_ERROR(CheckUtf8Text(urdf_xml));
  ARREF_RETURN_IF_ERROR(CheckJointTree(urdf_xml));
  auto impl = std::make_unique<Impl>();
  impl->urdf = urdf::parseURDF(urdf_xml);  // urdfdom reports details on its console log
  if (!impl->urdf || !impl->urdf->getRoot()) return Status::IoError("not a valid URDF (urdfdom could not parse it)");
  ARREF_RETURN_IF_ERROR(impl->LoadGeometry(base_dir, options));
  impl->CollectJoints(*impl->urdf->getRoot());
  for (const auto& joint : impl->joints) {
    if (joint.mimic_of.empty()) continue;
    const auto target = impl->joint_index.find(joint.mimic_of);
    if (target == impl->joint_index.end())
      return Status::InvalidArgument("joint '" + joint.name + "' mimics unknown joint '" + joint.mimic_of + "'");
    // CompleteJoints derives mimic joints from actuated ones only; a mimic of a mimic (itself
    // included) had no value there and threw (found by tests/fuzz/urdf_fuzz.cpp).
    if (!impl->joints[target->second].mimic_of.empty())
      return Status::InvalidArgument("joint '" + joint.name + "' mimics '" + joint.mimic_of +
                                     "', which is itself a mimic joint (mimic an actuated joint)");
  }
  spdlog::debug("robot '{}': {} links with geometry, {} joints", impl->urdf->getName(), impl->link_meshes.size(),
                impl->joints.size());
  return RobotModel(std::move(impl));
}

const std::string& RobotModel::name() const { return impl_->urdf->getName(); }
const std::string& RobotModel::root_link() const { return impl_->urdf->getRoot()->name; }

std::vector<JointInfo> RobotModel::ActuatedJoints() const {
  std::vector<JointInfo> out;
  for (const auto& j : impl_->joints)
    if (j.mimic_of.empty()) out.push_back(j);
  return out;
}

JointValues RobotModel::ClampedToLimits(const JointValues& given) const {
  JointValues out = given;
  for (auto& [name, value] : out) {
    auto it = impl_->joint_index.find(name);
    if (it == impl_->joint_index.end()) continue;
    const JointInfo& info = impl_->joints[it->second];
    if (info.has_limits) value = std::clamp(value, info.lower, info.upper);
  }
  return out;
}

Result<JointValues> RobotModel::CompleteJoints(const JointValues& given) const {
  for (const auto& [name, value] : given) {
    auto it = impl_->joint_index.find(name);
    if (it == impl_->joint_index.end()) {
      std::string known;
      for (const auto& j : ActuatedJoints()) known += (known.empty() ? "" : ", ") + j.name;
      return Status::InvalidArgument("unknown joint '" + name + "' (robot '" + this->name() + "' has: " + known + ")");
    }
    const JointInfo& info = impl_->joints[it->second];
    if (!info.mimic_of.empty())
      return Status::InvalidArgument("joint '" + name + "' mimics '" + info.mimic_of + "': set that one instead");
    if (!std::isfinite(value)) return Status::InvalidArgument("joint '" + name + "' value is not finite");
    if (info.has_limits && (value < info.lower - 1e-9 || value > info.upper + 1e-9))
      return Status::InvalidArgument("joint '" + name + "' = " + std::to_string(value) + " is outside its limits [" +
                                     std::to_string(info.lower) + ", " + std::to_string(info.upper) + "]");
  }
  JointValues out;
  for (const auto& j : impl_->joints) {
    if (!j.mimic_of.empty()) continue;
    auto it = given.find(j.name);
    out[j.name] = it != given.end() ? it->second : (j.has_limits ? std::clamp(0.0, j.lower, j.upper) : 0.0);
  }
  for (const auto& j : impl_->joints)
    if (!j.mimic_of.empty()) out[j.name] = j.mimic_multiplier * out.at(j.mimic_of) + j.mimic_offset;
  return out;
}

Result<std::map<std::string, Iso3>> RobotModel::LinkPoses(const JointValues& joints) const {
  ARREF_ASSIGN_OR_RETURN(const JointValues complete, CompleteJoints(joints));
  std::map<std::string, Iso3> poses;
  impl_->AddLinkPoses(*impl_->urdf->getRoot(), Iso3::Identity(), complete, &poses);
  return poses;
}

Result<TriangleMesh> RobotModel::PosedMesh(const JointValues& joints) const {
  const std::vector<std::string> all = GeometryLinks();
  return PosedMesh(joints, std::set<std::string>(all.begin(), all.end()));
}

std::vector<std::string> RobotModel::GeometryLinks() const {
  std::vector<std::string> links;
  for (const auto& [link, link_mesh] : impl_->link_meshes) links.push_back(link);
  return links;
}

Result<TriangleMesh> RobotModel::PosedMesh(const JointValues& joints, const std::set<std::string>& links) const {
  for (const std::string& link : links)
    if (!impl_->link_meshes.contains(link))
      return Status::InvalidArgument("robot '" + name() + "' has no link '" + link + "' with geometry");
  ARREF_ASSIGN_OR_RETURN(const auto poses, LinkPoses(joints));
  TriangleMesh mesh;
  for (const auto& [link, link_mesh] : impl_->link_meshes) {
    if (!links.contains(link)) continue;
    const auto pose = poses.find(link);  // every link lies on the tree from the root
    if (pose == poses.end()) return Status::Internal("robot link '" + link + "' has no pose");
    mesh.Append(link_mesh, pose->second);
  }
  return mesh;
}

const TriangleMesh* RobotModel::LinkMesh(const std::string& link) const {
  auto it = impl_->link_meshes.find(link);
  return it == impl_->link_meshes.end() ? nullptr : &it->second;
}

}  // namespace arref
